"""Does a trained UMSD network use its noisy input? The diagnosis of lab/NOTES.md section 13.3.

Usage: python lab/umsd_xt.py --model MODEL_DIR --corpus BANDAI2 [--neutral normal] [--clip ID]
       [--example ID] [--steps 10,100,500]

For one content clip and one style example (default: the first `--neutral` val clip, the first train `elderly`
walk): the prediction's mean absolute change when x_t is swapped for another `--neutral` val clip's x_t at the same
t, the prediction's error against the content and its highest ankle (metres, beside the content's) at each of
``--steps`` (x_t noised from the content). A network that denoises changes its prediction with x_t and errs less
at small t; one that copies its conditions does neither. With the content's own style as the example the answer
is the content, so the ankle shows whether a large movement (a kick) is taken from the condition.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from umsd_quality import load_clips, splits  # noqa: E402

from motionaug.augment.diffusion import NoiseSchedule, q_sample  # noqa: E402
from motionaug.augment.methods.umsd import load_umsd  # noqa: E402
from motionaug.augment.methods.umsd.training import x0_from_output  # noqa: E402
from motionaug.augment.motion.features import recover_from_ric  # noqa: E402
from motionaug.schemas.skeleton import T2M  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", type=Path, required=True)
    parser.add_argument("--corpus", type=Path, required=True)
    parser.add_argument("--neutral", default="normal")
    parser.add_argument("--clip", default=None, help="content clip id (default: the first --neutral val clip)")
    parser.add_argument("--example", default=None, help="style example id (default: the first train elderly walk)")
    parser.add_argument("--steps", default="10,100,500", help="diffusion steps t, comma-separated")
    args = parser.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(0)
    clips, parts = load_clips(args.corpus), splits(args.corpus)
    neutral_val = [clips[i] for i in parts["val"] if clips[i].style == args.neutral]
    source = clips[args.clip] if args.clip else neutral_val[0]
    other_clip = next(c for c in neutral_val if c.id != source.id)
    example = (
        clips[args.example]
        if args.example
        else next(
            clips[i] for i in sorted(parts["train"]) if clips[i].style == "elderly" and clips[i].content == "walk"
        )
    )
    model = load_umsd(args.model)
    as_tensor = lambda m: torch.from_numpy(model.normalizer.normalize(m[:96]).astype(np.float32))[None]  # noqa: E731
    content, other, style = as_tensor(source.motion), as_tensor(other_clip.motion), as_tensor(example.motion)
    other = torch.nn.functional.pad(other[:, : content.shape[1]], (0, 0, 0, max(0, content.shape[1] - other.shape[1])))
    ankles = list(T2M.feet_left[:1] + T2M.feet_right[:1])

    def highest_ankle(x: torch.Tensor) -> float:
        joints = recover_from_ric(torch.from_numpy(model.normalizer.denormalize(x[0].numpy())).float(), T2M.n_joints)
        return float(joints[:, ankles, 1].max())

    print(f"content {source.id} ({source.content}, highest ankle {highest_ankle(content):.2f} m), example {example.id}")
    schedule = NoiseSchedule.cosine()

    def predict(x_t: torch.Tensor, step: torch.Tensor) -> torch.Tensor:
        out = model.net(x_t, step, content, None, style, None)
        skip, prior = model.info.train.skip, model.skip_prior
        return x0_from_output(skip, schedule, x_t, step, out, prior, content, model.spectral)

    with torch.no_grad():
        for t in (int(v) for v in args.steps.split(",")):
            step = torch.tensor([t])
            own = predict(q_sample(schedule, content, step, torch.randn_like(content)), step)
            swapped = predict(q_sample(schedule, other, step, torch.randn_like(other)), step)
            print(
                f"t={t}: change when x_t is swapped {(own - swapped).abs().mean().item():.3f}, "
                f"error against the content {(own - content).abs().mean().item():.3f}, "
                f"highest ankle {highest_ankle(own):.2f} m"
            )


if __name__ == "__main__":
    main()
