"""Benchmark and learnability check of the synthetic style corpus.

Generates a corpus (default 1,000 clips), reports the wall time, then fits a linear probe (ridge
classifier on one-hot labels) to pooled features (mean, std, mean |x| over time of the 263-dim
features, z-scored with train statistics) of the train+val splits and reports style and content
accuracy on the held-out test split.
The corpus must be learnable: style >= 0.90 and content >= 0.95 (exit code 1 otherwise).

    .venv/bin/python bench/bench_synth.py --n-clips 1000 --seed 0
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import torch

from motionaug.augment.synth.corpus import generate_corpus, linear_probe_predict, pooled_descriptor, read_labels

REPO = Path(__file__).resolve().parents[1]


STYLE_MIN, CONTENT_MIN = 0.90, 0.95


def load_pooled(root: Path) -> tuple[np.ndarray, list[dict]]:
    labels = read_labels(root)
    x = np.stack([pooled_descriptor(np.load(root / "new_joint_vecs" / f"{r['id']}.npy")) for r in labels])
    return x, labels


def probe(
    x: np.ndarray, y: list[str], train: np.ndarray, test: np.ndarray, groups: list[str]
) -> tuple[float, dict[str, float]]:
    """Held-out accuracy of the linear probe, overall and within each group (e.g. per style)."""
    labels, group = np.array(y), np.array(groups)[test]
    hit = linear_probe_predict(x[train], list(labels[train]), x[test]) == labels[test]
    return float(hit.mean()), {str(g): float(hit[group == g].mean()) for g in sorted(set(group))}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n-clips", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None, help="keep the corpus here (default: a temp dir)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        root = args.out or Path(tmp) / "synth"
        summary = generate_corpus(root, args.n_clips, seed=args.seed)
        print(
            f"generated {summary.n_clips} clips ({summary.frames} frames) in {summary.seconds:.1f} s "
            f"-> {summary.n_clips / summary.seconds:.1f} clips/s; splits {summary.splits}"
        )
        x, labels = load_pooled(root)
    split = np.array([r["split"] for r in labels])
    train, test = np.flatnonzero(split != "test"), np.flatnonzero(split == "test")
    styles, contents = [r["style"] for r in labels], [r["content"] for r in labels]
    style_acc, style_per = probe(x, styles, train, test, styles)
    content_acc, content_per = probe(x, contents, train, test, styles)
    print(
        f"held-out ({len(test)} clips): style accuracy {style_acc:.3f} (need {STYLE_MIN}), "
        f"content accuracy {content_acc:.3f} (need {CONTENT_MIN})"
    )
    print("style accuracy per style:", {k: round(v, 3) for k, v in style_per.items()})
    print("content accuracy within each style:", {k: round(v, 3) for k, v in content_per.items()})
    return 0 if style_acc >= STYLE_MIN and content_acc >= CONTENT_MIN else 1


if __name__ == "__main__":
    raise SystemExit(main())
