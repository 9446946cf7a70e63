"""Clean-ups of UMSD's outputs after sampling, scored without sampling again: the examples' amplitude and
posture, the spectral ceiling and smoothing.

  python lab/umsd_rescore.py --corpus CORPUS --base BASE --work WORK --tag TAG --split val
      --variant SLACK:FROM_HZ:SMOOTH[:POSTURE[:AMPLITUDE]] [--variant ...]

Reads ``WORK/<tag>-<split>.json`` and ``-outputs.npz`` of a umsd_quality.py run made without clean-up
(``ceiling_slack``, ``smooth_frames`` 0, ``posture`` and ``amplitude`` network), applies to every output what
``UmsdStyleModel`` would with ``amplitude`` AMPLITUDE (``network`` or ``example``, default network),
``posture`` POSTURE (the same), ``ceiling_slack`` SLACK (0: none), ``ceiling_from_hz`` FROM_HZ and
``smooth_frames`` SMOOTH, in that order, restores the kept channels as sampled, and scores like
umsd_quality.py (same evaluators, same held-out clips). The examples' references are those the run's
``prepare`` picked (a run with style-contrast guidance, posture or amplitude: example). A variant ``0:0:0`` gives
the run's own figures back. Prints one row per variant.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import torch
from umsd_hooks import SpectralCeiling, signal_channels  # noqa: E402
from umsd_quality import by_style, load_clips, score, splits  # noqa: E402

from motionaug.augment.corpus import MotionClip  # noqa: E402
from motionaug.augment.methods.common import trajectory_channels  # noqa: E402
from motionaug.augment.methods.hooks import ShapeContext  # noqa: E402
from motionaug.augment.methods.shapers import with_amplitude, with_posture  # noqa: E402
from motionaug.augment.methods.shaping import nearest_root_motion  # noqa: E402
from motionaug.augment.methods.umsd import load_umsd  # noqa: E402
from motionaug.augment.methods.umsd.method import UmsdMethod  # noqa: E402
from motionaug.augment.motion.kinematics import gaussian_smooth_time  # noqa: E402
from motionaug.augment.outputs.shards import TransferOutput  # noqa: E402

Variant = tuple[float, float, float, str, str]


def smoothed(motion: np.ndarray, sigma: float) -> np.ndarray:
    """Raw features (T, F) with every channel but the foot contacts Gaussian-filtered over time."""
    if sigma <= 0:
        return motion
    signal = signal_channels(motion.shape[1])
    out = motion.copy()
    out[:, signal] = gaussian_smooth_time(torch.from_numpy(motion[:, signal]), sigma, time_dim=0).numpy()
    return out


def parse_variant(text: str) -> Variant:
    fields = text.split(":")
    slack, from_hz, smooth = (float(v) for v in fields[:3])
    posture, amplitude = (fields[3:] + ["network", "network"])[:2]
    if {posture, amplitude} - {"network", "example"}:
        raise SystemExit(f"variant {text}: posture and amplitude are network or example")
    return slack, from_hz, smooth, posture, amplitude


def cleaned(
    motion: np.ndarray, source: MotionClip, pair: tuple[torch.Tensor, torch.Tensor | None], model: Any, variant: Variant
) -> np.ndarray:
    """``motion`` (raw features) as ``UmsdStyleModel._transfer_batch`` would leave it under ``variant``; ``pair``:
    the stored style example and its reference."""
    slack, from_hz, smooth, posture, amplitude = variant
    if "example" in (posture, amplitude) and pair[1] is None:
        raise SystemExit("the run picked no references: rescore posture or amplitude: example on a run that did")
    norm = model.normalizer
    out = norm.normalize(np.asarray(motion, dtype=np.float32)).astype(np.float32)
    content = norm.normalize(source.motion).astype(np.float32)
    example, reference = pair[0].numpy(), None if pair[1] is None else pair[1].numpy()
    if amplitude == "example":
        out = with_amplitude(out, content, example, reference, 0.25)
    if posture == "example":
        out = with_posture(out, content, example, reference)
    out = SpectralCeiling(slack, from_hz)(out, ShapeContext(content, example, reference, model.info.fps))
    return smoothed(norm.denormalize(out).astype(np.float32), smooth)


def main(argv: list[str] | None = None) -> list[dict[str, Any]]:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--corpus", type=Path, required=True)
    parser.add_argument("--base", type=Path, required=True, help="base models with evaluators fit on the train split")
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--tag", required=True)
    parser.add_argument("--split", choices=("val", "test"), default="val")
    variant_help = "SLACK:FROM_HZ:SMOOTH[:POSTURE[:AMPLITUDE]] (repeatable)"
    parser.add_argument("--variant", action="append", required=True, help=variant_help)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument(
        "--repick", action="store_true", help="pick each example's reference again with the current code"
    )
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    run = json.loads((args.work / f"{args.tag}-{args.split}.json").read_text())
    params = run["transfer"]["params"]
    moments = (params.get("posture", "network"), params.get("amplitude", "network"))
    if params.get("ceiling_slack", 0) or params.get("smooth_frames", 0) or "example" in moments:
        raise SystemExit(f"{args.tag}: its outputs were already cleaned up; rescore a run without clean-up")
    keep = params.get("keep", "horizontal")
    kept = [] if keep == "none" else trajectory_channels(keep)
    model = load_umsd(args.work / run["train"]["dir"])
    clips = load_clips(args.corpus)
    ids = splits(args.corpus)
    held, train_by_style = by_style(clips, ids[args.split]), by_style(clips, ids["train"])
    raw = np.load(args.work / f"{args.tag}-{args.split}-outputs.npz")
    sources = {k.split("/", 1)[1]: clips[k.split("/", 1)[1]] for k in raw.keys()}
    references = run["transfer"].get("references", {})
    if args.repick:  # the run's pool was its held-out sources (umsd_quality.transfer)
        pool = {i: clip.motion for i, clip in sources.items()}
        references = {s: [nearest_root_motion(clips[e].motion, pool)[0]] for s, e in run["examples"].items()}
        print("references picked again:", {s: clips[r[0]].content for s, r in references.items()})
    pairs = {
        s: (
            UmsdMethod._stored(clips[e].motion, model),
            UmsdMethod._stored(clips[references[s][0]].motion, model) if references.get(s) else None,
        )
        for s, e in run["examples"].items()
    }
    rows = []
    print(f"{args.tag} ({args.split}), clean-ups of its outputs\n")
    head = "ceiling slack | from Hz | smooth frames | posture | amplitude | CRA | SRA (min) | per style | foot skating"
    print(f"| {head} |")
    print("|---:|---:|---:|---|---|---:|---|---|---:|")
    for text in args.variant:
        variant = parse_variant(text)
        outputs: dict[str, list[TransferOutput]] = defaultdict(list)
        for key in sorted(raw.keys()):
            style, source_id = key.split("/", 1)
            motion = cleaned(raw[key], sources[source_id], pairs[style], model, variant)
            motion[:, kept] = raw[key][:, kept]  # the content's as sampled (with pace: example, paced)
            outputs[style].append(TransferOutput(source_id=source_id, style=style, motion=motion, captions=[]))
        result = score(SimpleNamespace(base=args.base), outputs, held, train_by_style, sources)
        m = result["mean"]
        per = ", ".join(f"{s} {r['cra']:.0%} / {r['sra']:.0%}" for s, r in result["styles"].items())
        cells = (
            [f"{v:g}" for v in variant[:3]]
            + list(variant[3:])
            + [f"{m['cra']:.1%}", f"{m['sra']:.1%} ({m['sra_min']:.1%})", per]
        )
        print("| " + " | ".join(cells) + f" | {m['foot_skating']:.3f} |", flush=True)
        rows.append({"variant": variant, **result})
    return rows


if __name__ == "__main__":
    main(sys.argv[1:])
