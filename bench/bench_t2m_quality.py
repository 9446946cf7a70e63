"""Text-to-motion quality of pretrained base models on the held-out (test) split of a labelled corpus.

Usage: python bench/bench_t2m_quality.py --base DIR --corpus DIR [--scales 1,2,3] [--steps 20] [--threads 2]
       [--limit N] [--seed 0] [--all-captions]

For every test clip, its first caption (``--all-captions``: each of its captions) is generated with DDIM
(``--steps``) and classifier-free guidance at the clip's own length; the base models' content and style
classifiers then judge the generated joints against the clip's labels (CRA / SRA, the brief's targets: >= 0.80
content, >= 0.70 style). Also reported: the classifiers' accuracy on the real test clips (their ceiling here)
and text-to-motion retrieval R@1 of the motion encoder among 32 held-out candidates. Prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import torch

from motionaug.augment.eval.evaluation import Classifiers, load_classifiers
from motionaug.augment.eval.expansion import generate, one_row_per_caption
from motionaug.augment.metrics import retrieval_r_at_k
from motionaug.augment.training.base_models import BaseModels
from motionaug.augment.training.data import MotionSet, build_motion_set, iter_batches, read_clips, split_ids
from motionaug.augment.training.evaluators import classifier_accuracy
from motionaug.augment.training.pretrain import joints_of, skeleton_for


def accuracies(models: BaseModels, judges: Classifiers, data: MotionSet) -> dict[str, float]:
    """Content and style recognition of ``data`` by the evaluators (labelled clips only)."""
    skeleton = skeleton_for(models.normalizer.dim)
    joints, mask = joints_of(data, models.normalizer, skeleton, models.info.max_frames)
    out = {}
    for name, model, labels in (
        ("content", judges.content, data.content),
        ("style", judges.style, data.style),
    ):
        keep = labels >= 0
        if model is not None and bool(keep.any()):
            out[name] = classifier_accuracy(model, joints[keep], mask[keep], labels[keep])
    return out


@torch.no_grad()
def encoder_r1(models: BaseModels, data: MotionSet) -> float | None:
    if len(data) < 32:
        return None
    motions, texts = [], []
    for batch in iter_batches(data, 64, models.info.max_frames):
        motions.append(models.motion_encoder(batch.motion, batch.mask))
        texts.append(batch.text_embed)
    return retrieval_r_at_k(torch.cat(motions).numpy(), torch.cat(texts).numpy(), k=1, pool=32, seed=0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", type=Path, required=True)
    parser.add_argument("--corpus", type=Path, required=True)
    parser.add_argument("--scales", default="1,2,3", help="guidance scales, comma-separated; 0 = no guidance")
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--threads", type=int, default=os.cpu_count())
    parser.add_argument("--limit", type=int, default=None, help="only the first N test clips")
    parser.add_argument("--batch", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--all-captions", action="store_true", help="generate every caption of each clip, not the first"
    )
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    models = BaseModels.load(args.base)
    judges = load_classifiers(args.base)
    ids = split_ids(args.corpus, "test")[: args.limit]
    data = build_motion_set(
        read_clips(args.corpus, ids),
        models.normalizer,
        models.text_encoder,
        models.info.content_labels,
        models.info.style_labels,
    )
    report: dict[str, object] = {
        "clips": len(data),
        "real": accuracies(models, judges, data),
        "encoder_r1": encoder_r1(models, data),
    }
    if args.all_captions:
        data = one_row_per_caption(data)
        report["captions"] = len(data)
    for scale in (float(s) for s in args.scales.split(",")):
        start = time.perf_counter()
        generated = generate(models, data, scale or None, args.steps, args.batch, args.seed)
        report[f"guidance_{scale:g}"] = {
            **accuracies(models, judges, generated),
            "seconds": round(time.perf_counter() - start, 1),
        }
    report["load"] = os.getloadavg()
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
