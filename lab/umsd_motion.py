"""How UMSD's synthetic transfers move, against their sources and the true renders: root height, pace, roughness.

  python lab/umsd_motion.py --corpus SYNTH/corpus --work WORK --tag TAG --split val [--style depressed]
      [--by-content]

Reads ``WORK/<tag>-<split>-outputs.npz`` written by umsd_quality.py (no model runs) and renders each source
spec in the target style (the true transfer). Per style (and with ``--by-content`` per source content), means over
clips of: the root height (metres); the pace, the root's mean ground speed (m/s, at the corpus's 20 fps); the
roughness, the mean absolute second difference over frames of the
facing-frame joints (``ric``, metres per frame squared: frame-to-frame jitter, which no real motion here has much
of); and the motion, the mean over joint coordinates of their standard deviation over frames (metres).
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import numpy as np
from umsd_quality import RIC, load_clips  # noqa: E402

from motionaug.augment.motion.features import feature_slices  # noqa: E402
from motionaug.augment.synth import restyled  # noqa: E402
from motionaug.schemas.skeleton import T2M  # noqa: E402

COLUMNS = ("root_y", "pace", "roughness", "motion")
FPS = 20.0  # the synthetic corpus's frame rate
ROOT_LIN_VEL = feature_slices(T2M)["root_lin_vel"]  # the root's xz displacement per frame, in its facing frame


def measures(motion: np.ndarray) -> dict[str, float]:
    joints = np.asarray(motion, dtype=np.float64)[:, RIC]
    return {
        "root_y": float(np.mean(motion[:, 3])),
        "pace": float(np.linalg.norm(motion[:, ROOT_LIN_VEL], axis=1).mean() * FPS),
        "roughness": float(np.abs(np.diff(joints, n=2, axis=0)).mean()),
        "motion": float(joints.std(axis=0).mean()),
    }


def main(argv: list[str] | None = None) -> dict[str, dict[str, dict[str, float]]]:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--corpus", type=Path, required=True)
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--tag", required=True)
    parser.add_argument("--split", default="val")
    parser.add_argument("--style", action="append", help="only these target styles (repeatable)")
    parser.add_argument("--by-content", action="store_true")
    args = parser.parse_args(argv)
    clips = load_clips(args.corpus)
    outputs = np.load(args.work / f"{args.tag}-{args.split}-outputs.npz")
    groups: dict[str, dict[str, list[dict[str, float]]]] = defaultdict(lambda: defaultdict(list))
    for key in sorted(outputs.keys()):
        style, source_id = key.split("/", 1)
        if args.style and style not in args.style:
            continue
        source = clips[source_id]
        group = style
        if args.by_content:
            group += " / " + json.loads(source.meta["spec"])["content"]
        groups[group]["source"].append(measures(source.motion))
        groups[group]["true render"].append(measures(restyled(source, style).motion))
        groups[group]["output"].append(measures(outputs[key]))
    print(f"{args.tag} ({args.split})\n")
    print("| style | clips | " + " | ".join(f"{c}: source / true / output" for c in COLUMNS) + " |")
    print("|---|---:|" + "---|" * len(COLUMNS))
    result: dict[str, dict[str, dict[str, float]]] = {}
    for group, rows in groups.items():
        result[group] = {kind: {c: float(np.mean([r[c] for r in rs])) for c in COLUMNS} for kind, rs in rows.items()}
        cells = [" / ".join(f"{result[group][k][c]:.4f}" for k in ("source", "true render", "output")) for c in COLUMNS]
        print(f"| {group} | {len(rows['output'])} | " + " | ".join(cells) + " |")
    return result


if __name__ == "__main__":
    main()
