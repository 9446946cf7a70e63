"""Style-ERD transfer quality on held-out clips: CRA, SRA, FMD, foot skating, first-frames accuracy.

Usage: python lab/erd_quality.py --corpus CORPUS --evaluators BASE --work WORK [--split val|test]
       [--steps N] [--params JSON] [--neutral normal] [--tag NAME] [--threads 1]

``CORPUS``: a labelled corpus with split files (Bandai-2: ``motionaug corpus import-bvh ... --val-takes 3
--test-takes 3``; the synthetic corpus of ``bench/bench_pretrain.py synthetic``). ``BASE``: base models whose
evaluators were fit on its train split only (``motionaug pretrain --corpus CORPUS``).

1. Trains Style-ERD (``train_erd``) on the train split at a fixed step count (``--steps``; ``--params``: more
   ``ErdTrainConfig`` fields), into ``WORK/<tag>/model`` (reused when its ``erd.json`` has the same config).
2. Stylizes every ``--neutral`` clip of ``--split`` into every style the network learnt (neutral -> neutral too)
   with ``transfer``, the call the ``erd`` method plug-in makes, its content label given (the neutral branch's
   initial state by content).
3. Scores with ``lab/bandai2_quality.py``'s functions: CRA / SRA with Wilson 95% intervals, FMD on the evaluators'
   content features against the real ``--split`` clips of the style (both drawn to the same count) beside the
   real train-vs-held-out floor, foot skating against real clips.
4. First frames: style and content accuracy of the first ``--first-frames`` frames of each output, with the
   content label given and with unknown content (the learned unknown-content initial state).

The mean is over the styles other than neutral. Writes ``WORK/<tag>/<split>.json`` and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from motionaug.augment.corpus import Corpus
from motionaug.augment.eval.evaluation import classify, load_classifiers
from motionaug.augment.methods.common import labelled_training_clips
from motionaug.augment.methods.erd import ErdTrainConfig, load_erd, read_artifact, train_erd, transfer
from motionaug.augment.metrics import matched_fmd, mean_foot_skating, wilson_interval
from motionaug.augment.motion.features import features_to_joints
from motionaug.models.style_erd import NEUTRAL
from motionaug.schemas.skeleton import T2M


def train(args: argparse.Namespace, config: ErdTrainConfig) -> tuple[Path, dict[str, Any]]:
    folder = args.work / args.tag / "model"
    if (folder / "erd.json").is_file() and read_artifact(folder).train == config:
        art = read_artifact(folder)
        return folder, {"seconds": art.seconds, "reused": True}
    clips = labelled_training_clips(args.corpus, args.neutral)
    load = list(os.getloadavg())
    start = time.perf_counter()
    cpu = time.process_time()

    def progress(step: int, total: int, metrics: dict[str, float]) -> None:
        if step % 500 == 0:
            print(f"  step {step}/{total}", flush=True)

    train_erd(clips, folder, config, progress)
    return folder, {
        "seconds": time.perf_counter() - start,
        "cpu_seconds": time.process_time() - cpu,
        "clips": len(clips),
        "loadavg_before": load,
        "loadavg_after": list(os.getloadavg()),
        "reused": False,
    }


def accuracy(hits: int, n: int) -> dict[str, Any]:
    return {"acc": hits / n if n else float("nan"), "ci95": wilson_interval(hits, n), "n": n}


def score(args: argparse.Namespace, folder: Path) -> dict[str, Any]:
    net = load_erd(folder)
    judges = load_classifiers(args.evaluators)
    held_out = Corpus(args.corpus, split=args.split).by_style()
    train_real = Corpus(args.corpus, split="train").by_style()
    sources = held_out[args.neutral]
    label = {NEUTRAL: args.neutral}
    rows: dict[str, dict[str, Any]] = {}
    start = time.perf_counter()
    n_transfers = 0
    for style in net.config.styles:
        name = label.get(style, style)
        outputs = [
            transfer(net, [c.motion], style, None, c.content if c.content in net.config.contents else None)[0]
            for c in sources
        ]
        unknown = [transfer(net, [c.motion[: args.first_frames]], style)[0] for c in sources]
        n_transfers += len(outputs)
        joints = [features_to_joints(m) for m in outputs]
        content_probs, content_feats = classify(judges.content, joints)
        style_probs, _ = classify(judges.style, joints)
        cra = sum(judges.content_labels[int(i)] == c.content for i, c in zip(content_probs.argmax(1), sources))
        sra = sum(judges.style_labels[int(i)] == name for i in style_probs.argmax(1))
        real = [features_to_joints(c.motion) for c in held_out[name]]
        real_feats = classify(judges.content, real)[1]
        train_feats = classify(judges.content, [features_to_joints(c.motion) for c in train_real[name]])[1]
        fmd, n_fmd = matched_fmd(content_feats, real_feats, args.seed)
        floor, _ = matched_fmd(train_feats, real_feats, args.seed)
        first: dict[str, Any] = {}
        heads = [m[: args.first_frames] for m in outputs]
        for what, motions in (("content given", heads), ("unknown content", unknown)):
            fj = [features_to_joints(m) for m in motions]
            sp = classify(judges.style, fj)[0].argmax(1)
            cp = classify(judges.content, fj)[0].argmax(1)
            first[what] = {
                "sra": accuracy(int(sum(judges.style_labels[int(i)] == name for i in sp)), len(fj)),
                "cra": accuracy(
                    int(sum(judges.content_labels[int(i)] == c.content for i, c in zip(cp, sources))), len(fj)
                ),
            }
        predicted = np.bincount(style_probs.argmax(1), minlength=len(judges.style_labels))
        rows[name] = {
            "clips": len(outputs),
            "cra": accuracy(int(cra), len(outputs)),
            "sra": accuracy(int(sra), len(outputs)),
            "predicted_styles": {judges.style_labels[i]: int(n) for i, n in enumerate(predicted) if n},
            "fmd": fmd,
            "fmd_real_train_vs_held_out": floor,
            "fmd_samples": n_fmd,
            "foot_skating": mean_foot_skating(joints, T2M, 20.0),
            "foot_skating_real": mean_foot_skating(real, T2M, 20.0),
            f"first_{args.first_frames}_frames": first,
        }
    seconds = time.perf_counter() - start
    stylized = [r for s, r in rows.items() if s != args.neutral]
    key = f"first_{args.first_frames}_frames"
    mean = {
        "cra": float(np.mean([r["cra"]["acc"] for r in stylized])),
        "sra": float(np.mean([r["sra"]["acc"] for r in stylized])),
        "sra_min": float(min(r["sra"]["acc"] for r in stylized)),
        "fmd": float(np.mean([r["fmd"] for r in stylized])),
        "fmd_floor": float(np.mean([r["fmd_real_train_vs_held_out"] for r in stylized])),
        "foot_skating": float(np.mean([r["foot_skating"] for r in stylized])),
        "foot_skating_real": float(np.mean([r["foot_skating_real"] for r in stylized])),
        "first_frames_sra_content_given": float(np.mean([r[key]["content given"]["sra"]["acc"] for r in stylized])),
        "first_frames_sra_unknown_content": float(np.mean([r[key]["unknown content"]["sra"]["acc"] for r in stylized])),
        "first_frames_cra_content_given": float(np.mean([r[key]["content given"]["cra"]["acc"] for r in stylized])),
        "first_frames_cra_unknown_content": float(np.mean([r[key]["unknown content"]["cra"]["acc"] for r in stylized])),
    }
    return {"styles": rows, "mean": mean, "scoring_s": seconds, "transfers": n_transfers}


def table(result: dict[str, Any]) -> str:
    ff = result["first_frames"]
    lines = [
        f"Style-ERD ({result['tag']}, {result['train']['steps']} steps) "
        f"on {result['split']} clips of {result['corpus']}",
        "",
        f"| style | clips | CRA (95% CI) | SRA (95% CI) | FMD (real floor, n) | foot skating (real) "
        f"| first {ff} frames SRA: content given / unknown |",
        "|---|---|---|---|---|---|---|",
    ]
    for style, r in result["styles"].items():
        first = r[f"first_{ff}_frames"]
        lines.append(
            f"| {style} | {r['clips']} | {r['cra']['acc']:.1%} ({r['cra']['ci95'][0]:.0%}-{r['cra']['ci95'][1]:.0%}) "
            f"| {r['sra']['acc']:.1%} ({r['sra']['ci95'][0]:.0%}-{r['sra']['ci95'][1]:.0%}) "
            f"| {r['fmd']:.1f} ({r['fmd_real_train_vs_held_out']:.1f}, {r['fmd_samples']}) "
            f"| {r['foot_skating']:.3f} ({r['foot_skating_real']:.3f}) "
            f"| {first['content given']['sra']['acc']:.0%} / {first['unknown content']['sra']['acc']:.0%} |"
        )
    m = result["mean"]
    lines.append(
        f"| mean of stylized | | {m['cra']:.1%} | {m['sra']:.1%} (min {m['sra_min']:.1%}) | {m['fmd']:.1f} "
        f"({m['fmd_floor']:.1f}) | {m['foot_skating']:.3f} ({m['foot_skating_real']:.3f}) "
        f"| {m['first_frames_sra_content_given']:.0%} / {m['first_frames_sra_unknown_content']:.0%} |"
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--corpus", type=Path, required=True)
    parser.add_argument("--evaluators", type=Path, required=True, help="base models folder or its evaluators/")
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--split", choices=("val", "test"), default="val")
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--params", default="{}", help="JSON: more ErdTrainConfig fields")
    parser.add_argument("--neutral", default="normal", help="the corpus's name for the neutral style")
    parser.add_argument("--tag", default="main")
    parser.add_argument("--first-frames", type=int, default=10)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--train-only", action="store_true")
    args = parser.parse_args(argv)
    args.corpus, args.evaluators, args.work = args.corpus.resolve(), args.evaluators.resolve(), args.work.resolve()
    torch.set_num_threads(args.threads)
    config = ErdTrainConfig(steps=args.steps, threads=args.threads, **json.loads(args.params))
    folder, training = train(args, config)
    print(f"trained {folder}: {training}", flush=True)
    if args.train_only:
        return {"train": training}
    result = {
        "corpus": args.corpus.name,
        "split": args.split,
        "tag": args.tag,
        "first_frames": args.first_frames,
        "train": {"steps": args.steps, "params": json.loads(args.params), **training},
        "loadavg": list(os.getloadavg()),
        **score(args, folder),
    }
    out = args.work / args.tag / f"{args.split}.json"
    out.write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")
    print(table(result))
    return result


if __name__ == "__main__":
    main(sys.argv[1:])
