"""UMSD quality on held-out Bandai-2 takes (or the synthetic corpus): train once, transfer, score like bandai2_quality.

Usage: python lab/umsd_quality.py --corpus CORPUS --base BASE --work WORK [--split val|test]
       [--preset bandai] [--steps 2000] [--set key=value ...] [--hold-out STYLE] [--params JSON]
       [--neutral normal] [--example-content walk] [--threads 1] [--train-only]

``CORPUS``: a labelled corpus (Bandai-2 import or ``bench_pretrain.py synthetic``); ``BASE``: base models whose
evaluators were fit on ``CORPUS``'s train split only (``BASE/evaluators``).

Splits: with train/val/test split files the corpus's own. Without them, the fallback of pre-training
(``training_data.split_ids``: a stable hash of the clip id, 20% held out), which is what ``BASE``'s evaluators were
fit on; its held-out part is cut in two by a hash of the *take* id (a cut take's pieces stay together): half val,
half test. UMSD trains on the train part only, so no scored clip was seen by UMSD or the evaluators.

(a) Training (``train_umsd``, fixed ``--steps``, ``--preset`` sizes, ``--set`` overrides of ``UmsdTrainConfig``),
with ``--hold-out`` styles excluded (the unseen-style run, paper sec. 4.4). The folder
``WORK/model-<hash of config + train ids>`` is reused when it exists.
(b) Per target style (every style but the neutral one; with ``--hold-out`` only that one, unless ``--all-styles``):
``UmsdMethod.prepare`` from one example clip of the train split (the first take of ``--example-content`` in that
style, as in configs/bandai2-onthefly.yaml), then ``transfer`` of every neutral clip of ``--split`` (``--params``:
JSON merged into the method params, e.g. DDIM steps, ``keep``, ``transfer_noise_step``, ``window``).
(c) Scores with bandai2_quality's code: CRA / SRA (top-1 of the content / style evaluator against the source's
content / the target style, Wilson 95% intervals), FMD of content-evaluator features against the real ``--split``
clips of the style drawn to the same count (beside the real train-vs-held-out floor), foot skating; on synthetic
clips also each output's mean pose against its source rendered in every style (``posture_nearest``: whose render
is nearest; the true transfer is the target style's render). Writes ``WORK/<tag>-<split>.json`` (figures),
``WORK/<tag>-<split>-outputs.npz`` (each output's features, key ``<style>/<source id>``) and prints a Markdown
table. The machine's load average is recorded.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import sys
import time
from collections import defaultdict
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from motionaug.augment.corpus import Corpus, MotionClip
from motionaug.augment.eval.evaluation import classify, load_classifiers
from motionaug.augment.methods.base import ARTIFACT_JSON
from motionaug.augment.methods.umsd import UmsdTrainConfig, read_artifact, train_umsd
from motionaug.augment.methods.umsd.method import UmsdMethod
from motionaug.augment.metrics import matched_fmd, mean_foot_skating, wilson_interval
from motionaug.augment.motion.features import (
    feature_slices,
    features_to_joints,
)
from motionaug.augment.outputs.shards import TransferOutput
from motionaug.augment.synth import restyled
from motionaug.augment.training.data import split_ids
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.run_config import apply_overrides
from motionaug.schemas.skeleton import T2M
from motionaug.schemas.styles import StyleSpec

RIC = feature_slices(T2M)["ric"]

# Training presets (``UmsdTrainConfig`` fields). ``bandai``: the CPU preset chosen for a <= 45 min run on a shared
# 2-core machine (lab/NOTES.md section 13.1 has its profile); ``tiny``: a seconds-long smoke.
PRESETS: dict[str, dict[str, Any]] = {
    "default": {},
    "bandai": {"max_frames": 96, "batch_size": 6, "lr": 3e-4, "log_every": 100},
    "tiny": {"d_model": 32, "n_heads": 2, "ff_size": 64, "msm_blocks": 1, "d_state": 4, "batch_size": 2,
             "max_frames": 40, "log_every": 1},
}  # fmt: skip


def take_of(clip_id: str) -> str:
    """The take id of a clip (a cut take's pieces ``<take>_<start>_<end>`` share it)."""
    return re.sub(r"_\d{4,}_\d{4,}$", "", clip_id)


def splits(corpus: Path) -> dict[str, list[str]]:
    """train / val / test ids (see the module doc)."""
    if all((corpus / f"{s}.txt").is_file() for s in ("train", "val", "test")):
        return {s: [i for i in (corpus / f"{s}.txt").read_text().split() if i] for s in ("train", "val", "test")}
    held = split_ids(corpus, "test")
    val = [i for i in held if hashlib.sha256(take_of(i).encode()).digest()[0] % 2 == 0]
    return {"train": split_ids(corpus, "train"), "val": val, "test": [i for i in held if i not in set(val)]}


def load_clips(corpus: Path) -> dict[str, MotionClip]:
    return {c.id: c for c in Corpus(corpus, split_spans=False)}


def by_style(clips: dict[str, MotionClip], ids: list[str]) -> dict[str, list[MotionClip]]:
    """The corpus's clips among ``ids``, by style label."""
    out: dict[str, list[MotionClip]] = defaultdict(list)
    for i in ids:
        if i in clips:
            out[clips[i].style].append(clips[i])
    return out


def train_config(args: argparse.Namespace) -> UmsdTrainConfig:
    fields = {**PRESETS[args.preset], "steps": args.steps, "threads": args.threads}
    if args.hold_out:
        fields["exclude_styles"] = [args.hold_out]
    return UmsdTrainConfig(**{**fields, **apply_overrides({}, args.set)})


def train(args: argparse.Namespace, clips: dict[str, MotionClip], ids: list[str]) -> Path:
    config = train_config(args)
    key = hashlib.sha256(json.dumps([config.model_dump(mode="json"), sorted(ids)]).encode()).hexdigest()[:12]
    folder = args.work / f"model-{key}"
    if (folder / "umsd.json").is_file():
        print(f"reusing {folder}", flush=True)
        return folder
    rows = []
    for i in ids:
        clip = clips[i]
        rows.append(replace(clip, style="neutral") if clip.style == args.neutral else clip)
    load = os.getloadavg()[0]
    every = max(1, config.steps // 20)
    last = {"t": time.perf_counter()}

    def progress(step: int, total: int, metrics: dict[str, float]) -> None:
        if step % every == 0 or step == total:
            now = time.perf_counter()
            shown = {k: round(v, 3) for k, v in metrics.items()}
            print(f"  step {step}/{total} ({now - last['t']:.1f}s, load {os.getloadavg()[0]:.1f}) {shown}", flush=True)
            last["t"] = now

    print(f"training {config.steps} steps on {len(rows)} clips -> {folder} (load {load:.1f})", flush=True)
    train_umsd(rows, folder, config, progress)
    info = read_artifact(folder)
    facts = {"load_before": load, "load_after": os.getloadavg()[0], "steps_per_s": config.steps / info.seconds}
    (folder / "bench_facts.json").write_text(json.dumps(facts) + "\n")
    return folder


def example_for(style: str, train_ids: list[str], clips: dict[str, MotionClip], content: str) -> MotionClip:
    """The first train clip (by id) of ``style`` with content ``content`` (else of any content)."""
    of_style = sorted(i for i in train_ids if clips[i].style == style)
    pick = [i for i in of_style if clips[i].content == content] or of_style
    return clips[pick[0]]


def transfer(
    args: argparse.Namespace, model_dir: Path, styles: list[str], sources: list[MotionClip], examples: dict
) -> tuple[dict[str, list[TransferOutput]], dict[str, Any]]:
    params = {"neutral_style": args.neutral, "train": train_config(args).model_dump(mode="json")}
    params |= json.loads(args.params) if args.params else {}
    method = UmsdMethod(params)
    out: dict[str, list[TransferOutput]] = {}
    facts: dict[str, Any] = {"params": params, "prepare_s": {}, "references": {}, "transfer_s": {}}
    for style in styles:
        example = examples[style]
        spec = StyleSpec(
            name=style,
            words={"adjective": style},
            examples=[{"source": example.id, "description": f"a person moves in a {style} way"}],
        )
        start = time.perf_counter()
        folder = args.work / "styles" / f"{style}-{model_dir.name}"
        artifact = method.prepare(spec, [example], model_dir, sources, folder).folder  # sources: the content pool
        facts["prepare_s"][style] = time.perf_counter() - start
        facts["references"][style] = json.loads((artifact / ARTIFACT_JSON).read_text(encoding="utf-8"))["references"]
        model = method.load(artifact, model_dir)
        start = time.perf_counter()
        results = model.transfer(sources, seed=0)
        facts["transfer_s"][style] = time.perf_counter() - start
        out[style] = [r for r in results if isinstance(r, TransferOutput)]
        print(f"  {style}: {len(out[style])}/{len(sources)} clips in {facts['transfer_s'][style]:.1f}s", flush=True)
    return out, facts


def score(
    args: argparse.Namespace,
    outputs: dict[str, list[TransferOutput]],
    held: dict[str, list[MotionClip]],
    train_by_style: dict[str, list[MotionClip]],
    sources: dict[str, MotionClip],
) -> dict[str, Any]:
    """bandai2_quality.score's figures, on in-memory outputs."""
    judges = load_classifiers(args.base)
    rows: dict[str, Any] = {}
    truths: dict[str, dict[str, np.ndarray]] = {}  # source id -> style -> mean pose of its true render
    for style, outs in sorted(outputs.items()):
        joints = [features_to_joints(o.motion) for o in outs]
        content_probs, content_feats = classify(judges.content, joints)
        style_probs, _ = classify(judges.style, joints)
        contents = [sources[o.source_id].content for o in outs]
        cra_hits = int(sum(judges.content_labels[int(i)] == c for i, c in zip(content_probs.argmax(1), contents)))
        sra_hits = int(sum(judges.style_labels[int(i)] == style for i in style_probs.argmax(1)))
        real = [features_to_joints(c.motion) for c in held[style]]
        real_feats = classify(judges.content, real)[1]
        train_feats = classify(judges.content, [features_to_joints(c.motion) for c in train_by_style[style]])[1]
        try:  # too few clips for a 128-d covariance (a --limit smoke): no FMD
            fmd, n_fmd = matched_fmd(content_feats, real_feats, 0)
            floor, _ = matched_fmd(train_feats, real_feats, 0)
        except MotionDataError:
            fmd, n_fmd, floor = float("nan"), min(len(content_feats), len(real_feats)), float("nan")
        predicted = np.bincount(style_probs.argmax(1), minlength=len(judges.style_labels))
        misread: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))  # source content -> read as
        for i, c in zip(content_probs.argmax(1), contents):
            if judges.content_labels[int(i)] != c:
                misread[str(c)][judges.content_labels[int(i)]] += 1
        rows[style] = {
            "clips": len(outs),
            "cra": cra_hits / len(outs),
            "cra_95": wilson_interval(cra_hits, len(outs)),
            "sra": sra_hits / len(outs),
            "sra_95": wilson_interval(sra_hits, len(outs)),
            "predicted_styles": {lab: int(n) for lab, n in zip(judges.style_labels, predicted) if n},
            "content_misread": {c: dict(v) for c, v in sorted(misread.items())},
            "fmd": fmd,
            "fmd_real_train_vs_held_out": floor,
            "fmd_samples": n_fmd,
            "foot_skating": mean_foot_skating(joints, T2M, 20.0),
            "foot_skating_real": mean_foot_skating(real, T2M, 20.0),
            **true_postures(style, outs, sources, judges.style_labels, truths),
        }
    mean = {k: float(np.mean([r[k] for r in rows.values()])) for k in ("cra", "sra", "fmd", "foot_skating")}
    mean["sra_min"] = float(min(r["sra"] for r in rows.values()))
    hits = {k: sum(round(r[k] * r["clips"]) for r in rows.values()) for k in ("cra", "sra")}
    n = sum(r["clips"] for r in rows.values())
    mean |= {"cra_95": wilson_interval(hits["cra"], n), "sra_95": wilson_interval(hits["sra"], n), "clips": n}
    return {"styles": rows, "mean": mean}


def mean_pose(motion: np.ndarray) -> np.ndarray:
    """The clip's pose averaged over its frames: root-relative, facing-frame joints (the ``ric`` block), metres."""
    return np.asarray(motion, dtype=np.float64)[:, RIC].mean(axis=0)


def true_postures(
    style: str,
    outs: list[TransferOutput],
    sources: dict[str, MotionClip],
    styles: list[str],
    truths: dict[str, dict[str, np.ndarray]],
) -> dict[str, Any]:
    """Synthetic sources only: each output's mean pose against its source rendered in every judged style (the
    ground truth of every transfer of that clip). ``posture_nearest``: whose render is nearest; ``posture_error_m``:
    the mean joint distance to the target style's render. Empty for clips without a synthetic spec. ``truths``
    caches the renders' poses across the target styles."""
    if not outs or any("spec" not in (sources[o.source_id].meta or {}) for o in outs):
        return {}
    nearest: dict[str, int] = defaultdict(int)
    errors = []
    for o in outs:
        pose = mean_pose(o.motion).reshape(-1, 3)
        source = sources[o.source_id]
        if source.id not in truths:
            truths[source.id] = {s: mean_pose(restyled(source, s).motion).reshape(-1, 3) for s in styles}
        truth = truths[source.id]
        dist = {s: float(np.linalg.norm(pose - t, axis=1).mean()) for s, t in truth.items()}
        nearest[min(dist, key=dist.__getitem__)] += 1
        errors.append(dist[style])
    return {"posture_nearest": dict(sorted(nearest.items())), "posture_error_m": float(np.mean(errors))}


def table(result: dict[str, Any]) -> str:
    lines = [
        f"UMSD {result['tag']} on {result['split']} clips ({result['train']['steps']} steps, "
        f"{result['train']['steps_per_s']:.2f} steps/s, load {result['train']['load']:.1f})",
        "",
        "| style | clips | CRA (95% CI) | SRA (95% CI) | predicted | FMD (real floor, n) | foot skating (real) |",
        "|---|---|---|---|---|---|---|",
    ]
    for style, r in result["styles"].items():
        lines.append(
            f"| {style} | {r['clips']} | {r['cra']:.1%} ({r['cra_95'][0]:.0%}-{r['cra_95'][1]:.0%}) "
            f"| {r['sra']:.1%} ({r['sra_95'][0]:.0%}-{r['sra_95'][1]:.0%}) | {r['predicted_styles']} "
            f"| {r['fmd']:.2f} ({r['fmd_real_train_vs_held_out']:.2f}, {r['fmd_samples']}) "
            f"| {r['foot_skating']:.3f} ({r['foot_skating_real']:.3f}) |"
        )
    m = result["mean"]
    lines.append(
        f"| mean | {m['clips']} | {m['cra']:.1%} ({m['cra_95'][0]:.0%}-{m['cra_95'][1]:.0%}) "
        f"| {m['sra']:.1%} ({m['sra_95'][0]:.0%}-{m['sra_95'][1]:.0%}, min {m['sra_min']:.1%}) | "
        f"| {m['fmd']:.2f} | {m['foot_skating']:.3f} |"
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--corpus", type=Path, required=True)
    parser.add_argument("--base", type=Path, help="base models with evaluators fit on the train split")
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--split", choices=("val", "test"), default="val")
    parser.add_argument("--preset", choices=sorted(PRESETS), default="bandai")
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--set", action="append", default=[], help="UmsdTrainConfig override key=value")
    parser.add_argument("--hold-out", default="", help="a style left out of training, then transferred (sec. 4.4)")
    parser.add_argument("--params", default="", help="JSON merged into the method params (transfer settings)")
    parser.add_argument("--neutral", default="normal", help="the corpus's neutral style (synthetic: neutral)")
    parser.add_argument("--example-content", default="walk", help="content of each style's example clip")
    parser.add_argument("--all-styles", action="store_true", help="with --hold-out: the seen styles too")
    parser.add_argument("--limit", type=int, default=0, help="at most this many neutral clips (0: all)")
    parser.add_argument("--style", action="append", default=[], help="only these target styles (repeatable)")
    parser.add_argument("--tag", default="", help="name of the result file (default: main or heldout-STYLE)")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--train-only", action="store_true")
    args = parser.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(args.threads)
    clips = load_clips(args.corpus)
    ids = splits(args.corpus)
    model_dir = train(args, clips, [i for i in ids["train"] if i in clips])
    info = read_artifact(model_dir)
    facts_file = model_dir / "bench_facts.json"
    facts = json.loads(facts_file.read_text()) if facts_file.is_file() else {}
    train_facts = {
        "dir": model_dir.name,
        "steps": info.train.steps,
        "seconds": info.seconds,
        "steps_per_s": info.train.steps / info.seconds,
        "load": facts.get("load_before", float("nan")),
        "first": info.history[0],
        "last": info.history[-1],
    }
    print(json.dumps(train_facts), flush=True)
    if args.train_only:
        return train_facts
    held, train_by_style = by_style(clips, ids[args.split]), by_style(clips, ids["train"])
    sources = sorted(held[args.neutral], key=lambda c: c.id)
    if args.limit:
        sources = sources[: args.limit]
    every = sorted(s for s in held if s != args.neutral)
    styles = [args.hold_out] if args.hold_out and not args.all_styles else every
    styles = [s for s in styles if s in args.style] if args.style else styles
    examples = {s: example_for(s, ids["train"], clips, args.example_content) for s in styles}
    load = os.getloadavg()[0]
    outputs, tfacts = transfer(args, model_dir, styles, sources, examples)
    result = {
        "tag": args.tag or (f"heldout-{args.hold_out}" if args.hold_out else "main"),
        "split": args.split,
        "corpus": str(args.corpus),
        "train": train_facts,
        "examples": {s: e.id for s, e in examples.items()},
        "transfer": {**tfacts, "load": load, "sources": len(sources)},
        **score(args, outputs, held, train_by_style, {c.id: c for c in sources}),
    }
    (args.work / f"{result['tag']}-{args.split}.json").write_text(json.dumps(result, indent=1) + "\n")
    np.savez_compressed(
        args.work / f"{result['tag']}-{args.split}-outputs.npz",
        **{f"{style}/{o.source_id}": o.motion for style, outs in outputs.items() for o in outs},
    )
    print(table(result))
    return result


if __name__ == "__main__":
    main(sys.argv[1:])
