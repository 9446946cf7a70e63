"""The on-the-fly paper's Bandai-2 protocol (sec. 4.2, Table 2) on held-out takes, scored per style.

Usage: python lab/bandai2_quality.py --corpus BANDAI2 --base BASE --work WORK [--split test|val]
       [--method onthefly|stats] [--params JSON] [--examples 1] [--set key=value ...] [--guidance 1.5,2]
       [--foot-lock] [--prior-base BASE_WITHOUT_STYLE]

``BANDAI2``: ``motionaug corpus import-bvh ../shared/data/bandai/dataset-2 --out BANDAI2 --max-frames 196
--val-takes 3 --test-takes 3 --mean-std``;
``BASE``: ``motionaug pretrain --corpus BANDAI2 --out BASE`` (prior, encoder and evaluators fit on the train split).

Runs ``configs/bandai2-<method>.yaml`` through ``motionaug run`` (every ``normal`` clip of ``--split`` into each of the
7 styles, each learnt from ``--examples`` train takes of ``walk``), then scores every output with the base models'
evaluators, which never saw a ``--split`` take:
- CRA / SRA: the content / style classifier's top-1 on the output against the source's content / the target style,
  each with a Wilson 95% interval;
- FMD: Frechet distance of content-classifier features (the paper's definition) between the outputs of a style and
  the real ``--split`` takes of that style (every content), both drawn to the same count; beside it the same
  distance between real ``--split`` and real train takes of the style at that count (the floor a transfer can reach);
- foot skating of the outputs against the real ``--split`` takes of the style;
- prepare (fine-tune) seconds per style, from the run's artefact markers.
``--guidance``: the same sources transferred again from the run's artefacts at each ``style_guidance`` and scored
the same way (a transfer-time knob: the sweep needs no new fine-tune). ``--foot-lock``: every set scored again after
the ``foot_lock`` post-process.
The mean is over the 6 styles other than ``normal``. Prints a Markdown table and writes ``WORK/<method>-<split>.json``.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import torch

from motionaug.augment.corpus import Corpus
from motionaug.augment.eval.evaluation import classify, load_classifiers
from motionaug.augment.metrics import (
    matched_fmd,
    mean_foot_skating,
    wilson_interval,
)
from motionaug.augment.motion.features import features_to_joints
from motionaug.augment.motion.foot_lock import lock_feet
from motionaug.augment.outputs.run_dir import RunDir
from motionaug.augment.outputs.shards import TransferOutput, iter_shard_rows, row_motion
from motionaug.schemas.run_config import load_run_config
from motionaug.schemas.skeleton import T2M

REPO = Path(__file__).resolve().parents[1]
NEUTRAL = "normal"


def take_id(corpus: Path, first: str, take: int) -> str:
    """The clip id of take ``take`` of the same pair as ``first`` (the first piece when the take was cut)."""
    pair = re.match(r"^(?P<pair>.+)_\d{3}(_\d{4,}_\d{4,})?$", first)
    stem = f"{pair.group('pair') if pair else first}_{take:03d}"
    found = sorted(p.stem for p in (corpus / "new_joint_vecs").glob(f"{stem}*.npy"))
    return found[0] if found else stem


def run_protocol(args: argparse.Namespace) -> Path:
    """``motionaug run`` on the shipped config, with this bench's corpus, base models, split and output."""
    from motionaug.workflows.ray_executor import execute_run

    out = args.work / f"{args.method}-{args.split}"
    overrides = [
        f"corpus.path={args.corpus}",
        f"corpus.split={args.split}",
        f"output={out}",
        *args.set,
    ]
    if args.method != "stats":
        overrides.append(f"base_models.path={args.prior_base or args.base}")
    config = load_run_config(REPO / "configs" / f"bandai2-{args.method}.yaml", overrides)
    if args.params:
        params = {**config.method.params, **json.loads(args.params)}
        config = config.model_copy(update={"method": config.method.model_copy(update={"params": params})})
    if args.example_content != "walk":
        verb = CONTENT_VERBS[args.example_content]
        styles = []
        for style in config.styles:
            first = style.examples[0]
            source = take_id(args.corpus, f"dataset-2_{args.example_content}_{style.name}_001", 1)
            described = first.description.replace("walks forward", verb)
            styles.append(
                style.model_copy(
                    update={"examples": [first.model_copy(update={"source": source, "description": described})]}
                )
            )
        config = config.model_copy(update={"styles": styles})
    if args.examples > 1:
        styles = []
        for style in config.styles:
            first = style.examples[0]
            extra = [  # takes 002, 003, ... of the same pair (a cut take: its first piece, found in the corpus)
                first.model_copy(update={"source": take_id(args.corpus, first.source, i)})
                for i in range(2, args.examples + 1)
            ]
            styles.append(style.model_copy(update={"examples": [first, *extra]}))
        config = config.model_copy(update={"styles": styles})
    execute_run(config)
    return out


CONTENT_VERBS = {
    "walk": "walks forward",
    "run": "runs forward",
    "walk-turn-left": "walks and turns left",
    "walk-turn-right": "walks and turns right",
    "raise-up-both-hands": "raises both hands",
    "raise-up-left-hand": "raises the left hand",
    "raise-up-right-hand": "raises the right hand",
    "wave-both-hands": "waves both hands",
    "wave-left-hand": "waves the left hand",
    "wave-right-hand": "waves the right hand",
}
"""How an example of each Bandai-2 content is described (``--example-content``)."""

Outputs = dict[str, list[tuple[str, np.ndarray]]]
"""Per target style: (source clip id, output features) of every transfer."""


def run_outputs(run_dir: Path) -> Outputs:
    by_style: Outputs = defaultdict(list)
    for row in iter_shard_rows(run_dir, columns=["source_id", "style", "motion", "n_frames", "n_feats"]):
        by_style[row["style"]].append((row["source_id"], row_motion(row)))
    return by_style


def guided_outputs(run_dir: Path, args: argparse.Namespace, scale: float) -> Outputs:
    """The run's held-out sources transferred again from the run's own artefacts, with ``style_guidance`` = scale
    (a transfer-time knob: the fine-tuned weights are the run's, so a sweep costs transfers only)."""
    from motionaug.augment.methods.registry import create_method

    run = RunDir(run_dir)
    config = run.config()
    method = create_method(config["method"]["name"], config["method"]["params"])
    sources = Corpus(args.corpus, split=args.split).by_style()[NEUTRAL]
    trained = Path(config["base_models"]["path"])
    by_style: Outputs = defaultdict(list)
    for style in run.styles():
        model = method.load(run.artifact_dir(style), trained)
        model.params = model.params.model_copy(update={**json.loads(args.transfer_params), "style_guidance": scale})
        for out in model.transfer(sources, seed=args.seed):
            if isinstance(out, TransferOutput):
                by_style[style].append((out.source_id, out.motion))
    return by_style


def score(
    run_dir: Path, args: argparse.Namespace, by_style: Outputs | None = None, foot_lock: bool = False
) -> dict[str, Any]:
    """Score ``by_style`` (default: the run's shards) with the held-out evaluators, per style and over 6;
    ``foot_lock``: after ``augment.motion.foot_lock.lock_feet`` (the method's ``foot_lock`` post-process)."""
    torch.set_num_threads(args.threads)
    by_style = run_outputs(run_dir) if by_style is None else by_style
    judges = load_classifiers(args.base)
    held_out = Corpus(args.corpus, split=args.split).by_style()
    train = Corpus(args.corpus, split="train").by_style()
    sources = {c.id: c for c in held_out[NEUTRAL]}
    manifest = RunDir(run_dir).manifest()
    rows: dict[str, dict[str, Any]] = {}
    for style in sorted(by_style):
        outputs = by_style[style]
        joints = [features_to_joints(lock_feet(m) if foot_lock else m) for _, m in outputs]
        content_probs, content_feats = classify(judges.content, joints)
        style_probs, _ = classify(judges.style, joints)
        contents = [sources[s].content for s, _ in outputs]
        cra_hits = int(sum(judges.content_labels[int(i)] == c for i, c in zip(content_probs.argmax(1), contents)))
        sra_hits = int(sum(judges.style_labels[int(i)] == style for i in style_probs.argmax(1)))
        real = [features_to_joints(c.motion) for c in held_out[style]]
        real_feats = classify(judges.content, real)[1]
        train_feats = classify(judges.content, [features_to_joints(c.motion) for c in train[style]])[1]
        fmd, n_fmd = matched_fmd(content_feats, real_feats, args.seed)
        floor, _ = matched_fmd(train_feats, real_feats, args.seed)
        marker = manifest.artifacts.get(style)
        counts = np.bincount(style_probs.argmax(1), minlength=len(judges.style_labels))
        rows[style] = {
            "clips": len(outputs),
            "cra": cra_hits / len(outputs),
            "cra_95": wilson_interval(cra_hits, len(outputs)),
            "sra": sra_hits / len(outputs),
            "sra_95": wilson_interval(sra_hits, len(outputs)),
            "predicted_styles": {lab: int(n) for lab, n in sorted(zip(judges.style_labels, counts)) if n},
            "fmd": fmd,
            "fmd_real_train_vs_held_out": floor,
            "fmd_samples": n_fmd,
            "foot_skating": mean_foot_skating(joints, T2M, 20.0),
            "foot_skating_real": mean_foot_skating(real, T2M, 20.0),
            "prepare_s": marker.seconds if marker else None,
        }
    stylized = [r for s, r in rows.items() if s != NEUTRAL]
    mean = {k: float(np.mean([r[k] for r in stylized])) for k in ("cra", "sra", "fmd", "foot_skating", "prepare_s")}
    mean["sra_min"] = float(min(r["sra"] for r in stylized))
    return {
        "split": args.split,
        "method": args.method,
        "run": str(run_dir),
        "examples_per_style": args.examples,
        "styles": rows,
        "mean_over_6": mean,
        "transfer_s": manifest.stages["transfer"].seconds,
        "evaluators": str(args.base),
        "foot_lock_in_scoring": foot_lock,
    }


def table(result: dict[str, Any]) -> str:
    lines = [
        f"{result['method']} on Bandai-2 {result['split']} takes ({result['examples_per_style']} example(s) per style)",
        "",
        "| style | clips | CRA (95% CI) | SRA (95% CI) | FMD (real floor, n) | foot skating (real) | prepare s |",
        "|---|---|---|---|---|---|---|",
    ]
    for style, r in result["styles"].items():
        lines.append(
            f"| {style} | {r['clips']} | {r['cra']:.1%} ({r['cra_95'][0]:.0%}-{r['cra_95'][1]:.0%}) "
            f"| {r['sra']:.1%} ({r['sra_95'][0]:.0%}-{r['sra_95'][1]:.0%}) "
            f"| {r['fmd']:.2f} ({r['fmd_real_train_vs_held_out']:.2f}, {r['fmd_samples']}) "
            f"| {r['foot_skating']:.3f} ({r['foot_skating_real']:.3f}) | {r['prepare_s'] or 0:.1f} |"
        )
    m = result["mean_over_6"]
    lines.append(
        f"| mean of 6 | | {m['cra']:.1%} | {m['sra']:.1%} (min {m['sra_min']:.1%}) | {m['fmd']:.2f} "
        f"| {m['foot_skating']:.3f} | {m['prepare_s']:.1f} |"
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--corpus", type=Path, required=True)
    parser.add_argument("--base", type=Path, required=True, help="base models: the evaluators (and the prior)")
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument(
        "--prior-base",
        type=Path,
        default=None,
        help="base models the method fine-tunes, when not --base (e.g. pre-trained without the scored style)",
    )
    parser.add_argument("--split", choices=("val", "test"), default="test")
    parser.add_argument("--method", default="onthefly")
    parser.add_argument("--params", default="", help="JSON merged into the config's method params")
    parser.add_argument("--examples", type=int, default=1, help="example takes per style (001, 002, ...)")
    parser.add_argument(
        "--example-content", default="walk", choices=sorted(CONTENT_VERBS), help="content of the example takes"
    )
    parser.add_argument("--set", action="append", default=[], help="run-config override key=value")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--score-only", action="store_true", help="score the existing run folder")
    parser.add_argument(
        "--transfer-params", default="{}", help="JSON of transfer-time params for the --guidance re-transfers"
    )
    parser.add_argument(
        "--foot-lock",
        action="store_true",
        help="also score every output after the foot_lock post-process (WORK/<name>-locked.json)",
    )
    parser.add_argument(
        "--guidance",
        default="",
        help="comma-separated style_guidance values: re-transfer the run's sources from its artefacts with each "
        "and score them too (WORK/<method>-<split>-w<value>.json)",
    )
    args = parser.parse_args(argv)
    args.corpus, args.base, args.work = args.corpus.resolve(), args.base.resolve(), args.work.resolve()
    args.work.mkdir(parents=True, exist_ok=True)
    run_dir = args.work / f"{args.method}-{args.split}" if args.score_only else run_protocol(args)
    result = score(run_dir, args)
    (args.work / f"{args.method}-{args.split}.json").write_text(json.dumps(result, indent=1) + "\n")
    print(table(result))
    if args.foot_lock:
        locked = score(run_dir, args, foot_lock=True)
        (args.work / f"{args.method}-{args.split}-locked.json").write_text(json.dumps(locked, indent=1) + "\n")
        print("\nwith foot_lock\n" + table(locked))
    for value in filter(None, args.guidance.split(",")):
        outputs = guided_outputs(run_dir, args, float(value))
        for lock in (False, True) if args.foot_lock else (False,):
            guided = score(run_dir, args, outputs, foot_lock=lock)
            guided["style_guidance"] = float(value)
            guided["transfer_params"] = json.loads(args.transfer_params)
            tag = "".join(f"-{k}={v}" for k, v in sorted(json.loads(args.transfer_params).items()))
            name = f"{args.method}-{args.split}-w{value}{tag}{'-locked' if lock else ''}"
            (args.work / f"{name}.json").write_text(json.dumps(guided, indent=1) + "\n")
            print(f"\nstyle_guidance {value}{', foot_lock' if lock else ''}\n" + table(guided))
    return result


if __name__ == "__main__":
    main(sys.argv[1:])
