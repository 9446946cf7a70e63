"""Where UMSD's frame-to-frame shake comes from: one prediction from a noised true transfer, and the sampled outputs.

  python lab/umsd_shake.py --corpus SYNTH/corpus --work WORK --tag TAG --split val --style depressed
      [--clips 16] [--steps 1,10,50,100,200,400,700,999]

Reads ``WORK/<tag>-<split>.json`` and ``-outputs.npz`` (umsd_quality.py on the synthetic corpus). For the
first ``--clips`` neutral clips of the split, the true transfer into ``--style`` (the source rendered in that
style) is noised to each t of ``--steps`` and the tag's network predicts x0 once, conditioned on the source and the
tag's style example. Prints the roughness (the mean absolute second difference over frames of the facing-frame
joints, metres per frame squared, as bench_umsd_motion.py) of those predictions, of the true transfers and of the
tag's sampled outputs of the same clips. A prediction much smoother than the sampled output means the shake builds
up over the sampling steps, each step taking the last one's shake as signal.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from umsd_motion import measures  # noqa: E402
from umsd_quality import load_clips, splits  # noqa: E402

from motionaug.augment.diffusion import NoiseSchedule, q_sample  # noqa: E402
from motionaug.augment.methods.umsd import load_umsd  # noqa: E402
from motionaug.augment.methods.umsd.method import UmsdMethod  # noqa: E402
from motionaug.augment.methods.umsd.training import pace_channels, x0_from_output  # noqa: E402
from motionaug.augment.synth import restyled  # noqa: E402


def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--corpus", type=Path, required=True)
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--tag", required=True)
    parser.add_argument("--split", default="val")
    parser.add_argument("--style", required=True)
    parser.add_argument("--clips", type=int, default=16)
    parser.add_argument("--steps", default="1,10,50,100,200,400,700,999")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    run = json.loads((args.work / f"{args.tag}-{args.split}.json").read_text())
    model = load_umsd(args.work / run["train"]["dir"])
    clips, ids = load_clips(args.corpus), splits(args.corpus)
    outputs = np.load(args.work / f"{args.tag}-{args.split}-outputs.npz")
    sources = [clips[i] for i in sorted(ids[args.split]) if i in clips and clips[i].style == "neutral"]
    sources = [c for c in sources if f"{args.style}/{c.id}" in outputs][: args.clips]
    example = UmsdMethod._stored(clips[run["examples"][args.style]].motion, model)[None]
    norm, crop = model.normalizer, model.info.train.max_frames
    schedule, generator = NoiseSchedule.cosine(), torch.Generator().manual_seed(0)
    as_tensor = lambda m: torch.from_numpy(norm.normalize(m[:crop]).astype(np.float32))[None]  # noqa: E731
    rough = lambda m: measures(m)["roughness"]  # noqa: E731
    result = {
        "true transfer": float(np.mean([rough(restyled(c, args.style).motion) for c in sources])),
        "sampled output": float(np.mean([rough(outputs[f"{args.style}/{c.id}"]) for c in sources])),
    }
    train = model.info.train
    with torch.no_grad():
        for t in (int(v) for v in args.steps.split(",")):
            values = []
            for clip in sources:
                target, content = as_tensor(restyled(clip, args.style).motion), as_tensor(clip.motion)
                mask = torch.ones(1, target.shape[1], dtype=torch.bool)
                step = torch.tensor([t])
                x_t = q_sample(schedule, target, step, torch.randn(target.shape, generator=generator))
                cond = model.net.condition(content, mask, example, torch.ones(1, example.shape[1], dtype=torch.bool))
                out = model.net.denoise(x_t, step, cond, mask)
                x0 = x0_from_output(
                    train.skip, schedule, x_t, step, out, model.skip_prior, content, model.spectral, mask,
                    pace_channels(train),
                )  # fmt: skip
                values.append(rough(norm.denormalize(x0[0].numpy())))
            result[f"one prediction at t={t}"] = float(np.mean(values))
    print(f"{args.tag} ({args.split}, {args.style}, {len(sources)} clips): roughness, m/frame^2\n")
    print("| motion | roughness |\n|---|---:|")
    for name, value in result.items():
        print(f"| {name} | {value:.4f} |")
    return result


if __name__ == "__main__":
    main()
