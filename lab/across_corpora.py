"""On-the-fly transfer across corpora: a Bandai-2 style onto synthetic content, a synthetic style onto Bandai-2 content.

Usage: python lab/across_corpora.py --synth-corpus SYNTH --synth-base SYNTH_BASE --bandai-corpus BANDAI2
       --bandai-base BANDAI2_BASE --work WORK [--direction both|bandai-to-synth|synth-to-bandai]
       [--styles active,...] [--n-content 36] [--params JSON] [--transfer-params JSON] [--threads 1]

``SYNTH``/``SYNTH_BASE``: ``bench/bench_pretrain.py synthetic`` (the corpus and its base models); ``BANDAI2``/
``BANDAI2_BASE``: the corpus and base models of ``lab/bandai2_quality.py``. Each base's evaluators are fit on its
corpus's train split only.

- ``bandai-to-synth``: each Bandai-2 style of ``configs/bandai2-onthefly.yaml`` learnt from that config's example (take
  001 of ``walk``, a train take) with the config's method params, on the SYNTHETIC base prior (the content corpus's,
  as a user with a synthetic corpus runs it), transferred onto ``--n-content`` neutral clips of the synthetic test
  split, round-robin over contents.
- ``synth-to-bandai``: each synthetic style learnt from one train-split ``walk`` clip of that style (the example
  ``bench_onthefly.pick_clips`` takes), on the BANDAI-2 base prior, transferred onto every ``normal`` clip of the
  Bandai-2 test split.

In both the semantic loss's pool is the content corpus's train-split neutral clips (up to ``POOL_CLIPS``, a seeded
draw, as a run with ``corpus.pool_split: train`` draws it), so no model trains on a scored clip. SRA is scored with
the style classifier of the example's corpus, CRA with the content classifier of the content's corpus, each with a
Wilson 95% interval; beside them what the same classifiers make of the untouched inputs. ``--transfer-params``
(transfer-time knobs: ``style_guidance``, ``foot_lock``) transfers the same clips again from the same fine-tunes and
scores that too. Held-out means the test split the content base was pre-trained without (its split files, or the
stable hash split ``augment.training.data.split_ids`` falls back to). Fine-tunes and outputs are kept under
``WORK/<direction>/<style>`` and reused by a rerun with the same params and clips (``--transfer-only`` makes them
without the evaluators; a later run scores them). Prints a Markdown table, writes ``WORK/across.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))  # lab reuses the quality benches' loaders
from bench_onthefly import pick_clips, style_words  # noqa: E402

from motionaug.augment.corpus import Corpus
from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.corpus.style_examples import load_style_examples
from motionaug.augment.eval.evaluation import Classifiers, classify, load_classifiers
from motionaug.augment.methods.onthefly import POOL_CLIPS, OnTheFlyMethod, parse_params
from motionaug.augment.metrics import wilson_interval
from motionaug.augment.motion.features import features_to_joints
from motionaug.augment.outputs.checksums import TIMINGS_FILE
from motionaug.augment.outputs.shards import TransferOutput
from motionaug.augment.training.data import read_clips, split_ids
from motionaug.schemas.run_config import load_run_config
from motionaug.schemas.styles import StyleExample, StyleSpec

REPO = Path(__file__).resolve().parents[1]
BANDAI_CONFIG = REPO / "configs" / "bandai2-onthefly.yaml"
BANDAI_NEUTRAL, SYNTH_NEUTRAL = "normal", "neutral"


def held_out(corpus: Path, style: str) -> list[MotionClip]:
    """The ``style`` clips of ``corpus``'s test split, in id order."""
    return [c for c in read_clips(corpus, split_ids(corpus, "test")) if c.style == style]


def split_source(corpus: Path) -> str:
    """Where ``corpus``'s test split comes from: its split files or the fallback hash split of the ids."""
    return "test.txt" if (corpus / "test.txt").is_file() else "hash split (no split files)"


def round_robin(clips: Sequence[MotionClip], n: int) -> list[MotionClip]:
    """Up to ``n`` clips taken in turn from each content (id order within a content)."""
    groups: dict[str, list[MotionClip]] = {}
    for clip in clips:
        groups.setdefault(clip.content or "", []).append(clip)
    chosen: list[MotionClip] = []
    while len(chosen) < n and any(groups.values()):
        for group in groups.values():
            if group and len(chosen) < n:
                chosen.append(group.pop(0))
    return chosen


def bandai_styles(corpus: Path) -> tuple[list[tuple[StyleSpec, list[MotionClip]]], dict[str, Any]]:
    """(style, example clips) of every non-neutral style of the shipped Bandai-2 config, and its method params."""
    config = load_run_config(BANDAI_CONFIG, [f"corpus.path={corpus}"])
    train = set(split_ids(corpus, "train"))
    out = []
    for spec in config.styles:
        if spec.name == BANDAI_NEUTRAL:
            continue
        ids = [e.source for e in spec.examples]
        if not train.issuperset(ids):  # no scored clip is Bandai-2's, so this is a deviation, not a leak
            print(f"warning: {spec.name} example {ids} is not in {corpus}'s train split", file=sys.stderr)
        clips, missing = Corpus(corpus).load(ids, files=ids)
        if missing:
            raise SystemExit(f"{spec.name}: {missing[0].id}: {missing[0].reason}")
        examples = load_style_examples(spec, {c.id: c for c in clips})
        for clip, source in zip(examples, ids):
            clip.meta["split"] = "train" if source in train else "held out"
        out.append((spec, examples))
    return out, dict(config.method.params)


def synth_styles(corpus: Path, names: Sequence[str]) -> list[tuple[StyleSpec, list[MotionClip]]]:
    """(style, example) per synthetic style: the first train-split ``walk`` clip, described as bench_onthefly does."""
    clips = list(Corpus(corpus))
    out = []
    for name in names:
        example, _ = pick_clips(clips, name, "walk", 0)
        if example.meta.get("split") != "train":
            raise SystemExit(f"{name}: example {example.id} is not a train-split clip")
        words = style_words(name)
        forms = (words.adjective, words.adverb or "@", *words.phrases)
        text = next((c.text for c in example.captions if any(f in c.text for f in forms)), None)
        description = text or f"a person walks {words.adverb or words.phrases[0]}"
        spec = StyleSpec(name=name, words=words, examples=[StyleExample(source=example.id, description=description)])
        out.append((spec, load_style_examples(spec, {example.id: example})))
    return out


def recognition(
    judges_style: Classifiers, judges_content: Classifiers, joints: list[np.ndarray], contents: list[str], style: str
) -> dict[str, Any]:
    """SRA (example corpus's style classifier says ``style``) and CRA (content corpus's classifier says the clip's
    content), with Wilson 95% intervals and what the style classifier said instead."""
    assert judges_style.style is not None and judges_content.content is not None
    style_probs, _ = classify(judges_style.style, joints)
    content_probs, _ = classify(judges_content.content, joints)
    said = [judges_style.style_labels[int(i)] for i in style_probs.argmax(1)]
    content_said = [judges_content.content_labels[int(i)] for i in content_probs.argmax(1)]
    sra_hits = sum(s == style for s in said)
    cra_hits = sum(c == t for c, t in zip(content_said, contents))
    n = len(joints)
    return {
        "clips": n,
        "sra": sra_hits / n,
        "sra_95": wilson_interval(sra_hits, n),
        "cra": cra_hits / n,
        "cra_95": wilson_interval(cra_hits, n),
        "styles_said": dict(Counter(said).most_common()),
        "contents_missed": dict(Counter(f"{t} -> {c}" for c, t in zip(content_said, contents) if c != t)),
    }


def train_pool(corpus: Path, style: str, seed: int = 0) -> list[MotionClip]:
    """The L_s pool as a run with ``corpus.pool_split: train`` draws it: up to ``POOL_CLIPS`` ``style`` clips of the
    train split, a seeded draw (no scored clip is ever in it)."""
    clips = [c for c in read_clips(corpus, split_ids(corpus, "train")) if c.style == style]
    drawn = np.random.default_rng(seed).permutation(len(clips))[:POOL_CLIPS]
    return [clips[int(i)] for i in sorted(drawn)]


Outputs = list[tuple[str, np.ndarray]]
"""(source clip id, output features) per transfer."""


def stylize(
    method: OnTheFlyMethod,
    spec: StyleSpec,
    examples: list[MotionClip],
    pool: list[MotionClip],
    content: list[MotionClip],
    prior_base: Path,
    folder: Path,
    transfer_params: dict[str, Any] | None,
) -> tuple[Outputs, Outputs | None, dict[str, Any]]:
    """Fine-tune ``spec`` on ``prior_base`` with ``pool`` as the L_s pool, transfer ``content``; with
    ``transfer_params`` (transfer-time knobs such as ``style_guidance``, ``foot_lock``) transfer it again from the same
    fine-tune. Returns (outputs, outputs with ``transfer_params`` or None, facts); kept in ``folder`` and reused when
    the params and clips match."""
    key = {
        "params": method.params.model_dump(mode="json"),
        "transfer_params": transfer_params,
        "pool": [c.id for c in pool],
        "content": [c.id for c in content],
        "prior": str(prior_base),
    }
    facts_file, motions_file = folder / "outputs.json", folder / "outputs.npz"
    if facts_file.is_file() and motions_file.is_file():
        facts = json.loads(facts_file.read_text())
        if facts["key"] == key:
            with np.load(motions_file) as saved:
                outs = [(i, saved[f"m{n}"]) for n, i in enumerate(facts["source_ids"])]
                again = [(i, saved[f"v{n}"]) for n, i in enumerate(facts.get("variant_ids") or [])]
            return outs, again if transfer_params is not None else None, facts
    artifact = method.prepare(spec, examples, prior_base, pool, folder / "artifact").folder
    timings = json.loads((artifact / TIMINGS_FILE).read_text())
    info = json.loads((artifact / "artifact.json").read_text())
    model = method.load(artifact, prior_base)
    start = time.perf_counter()
    outs = [(o.source_id, o.motion) for o in model.transfer(content, seed=0) if isinstance(o, TransferOutput)]
    transfer_s = time.perf_counter() - start
    again: Outputs = []
    if transfer_params is not None:
        model.params = model.params.model_copy(update=transfer_params)
        again = [(o.source_id, o.motion) for o in model.transfer(content, seed=0) if isinstance(o, TransferOutput)]
    facts = {
        "key": key,
        "source_ids": [i for i, _ in outs],
        "variant_ids": [i for i, _ in again],
        "tempo": info["tempo"],
        "steps": len(info["loss_curve"]),
        "pool_clips": info["pool_clips"],
        "finetune_s": timings.get("finetune_s"),
        "transfer_s": transfer_s,
    }
    arrays = {f"m{n}": m for n, (_, m) in enumerate(outs)} | {f"v{n}": m for n, (_, m) in enumerate(again)}
    np.savez(motions_file, **arrays)
    facts_file.write_text(json.dumps(facts, indent=1) + "\n")
    return outs, again if transfer_params is not None else None, facts


def run_direction(
    name: str,
    styles: list[tuple[StyleSpec, list[MotionClip]]],
    pool: list[MotionClip],
    content: list[MotionClip],
    content_corpus: Path,
    prior_base: Path,
    judges: tuple[Classifiers, Classifiers] | None,
    params: dict[str, Any],
    transfer_params: dict[str, Any] | None,
    work: Path,
) -> dict[str, Any]:
    """Stylize ``content`` in each style and score it with ``judges`` (style classifier's, content classifier's);
    ``judges`` None: transfers only (kept for a later scoring run)."""
    method = OnTheFlyMethod(parse_params(params))
    contents = [c.content or "" for c in content]
    inputs = [features_to_joints(c.motion) for c in content]
    by_id = {c.id: c for c in content}

    def score(outs: Outputs, style: str) -> dict[str, Any]:
        assert judges is not None
        joints = [features_to_joints(m) for _, m in outs]
        return recognition(*judges, joints, [by_id[i].content or "" for i, _ in outs], style)

    rows = []
    for spec, examples in styles:
        outs, again, facts = stylize(
            method, spec, examples, pool, content, prior_base, work / name / spec.name, transfer_params
        )
        row = {
            "style": spec.name,
            "example": spec.examples[0].source,
            "example_split": examples[0].meta.get("split"),
            "description": spec.examples[0].description,
            "rejected": len(content) - len(outs),
            **{k: facts[k] for k in ("tempo", "steps", "pool_clips", "finetune_s", "transfer_s")},
        }
        if judges is not None:
            row |= score(outs, spec.name)
            row["input"] = recognition(*judges, inputs, contents, spec.name)
            if again is not None:
                row["transfer_params"] = score(again, spec.name)
            print(f"{name} {spec.name}: SRA {row['sra']:.0%} CRA {row['cra']:.0%}", flush=True)
        rows.append(row)
    result = {
        "direction": name,
        "prior": str(prior_base),
        "content_clips": len(content),
        "content_split": f"test of {content_corpus} ({split_source(content_corpus)})",
        "content_ids": [c.id for c in content],
        "content_counts": dict(Counter(contents)),
        "pool": f"{len(pool)} {content_corpus} train-split clips",
        "params": params,
        "transfer_params": transfer_params,
        "rows": rows,
    }
    if judges is not None:
        mean = {k: float(np.mean([r[k] for r in rows])) for k in ("sra", "cra", "finetune_s")}
        mean["sra_min"] = float(min(r["sra"] for r in rows))
        mean["input_sra"] = float(np.mean([r["input"]["sra"] for r in rows]))
        mean["input_cra"] = rows[0]["input"]["cra"]
        if transfer_params is not None:
            mean["transfer_params_sra"] = float(np.mean([r["transfer_params"]["sra"] for r in rows]))
            mean["transfer_params_cra"] = float(np.mean([r["transfer_params"]["cra"] for r in rows]))
            mean["transfer_params_sra_min"] = float(min(r["transfer_params"]["sra"] for r in rows))
        result |= {"style_evaluator": judges[0].source, "content_evaluator": judges[1].source, "mean": mean}
    return result


def table(result: dict[str, Any]) -> str:
    variant = result["transfer_params"]
    head = "| style | example (split) | SRA (95% CI) | CRA (95% CI) | input SRA / CRA | tempo | fine-tune s |"
    lines = [
        f"{result['direction']}: {result['content_clips']} held-out neutral clips, {result['content_split']}, "
        f"prior {result['prior']}, L_s pool {result['pool']}",
        "",
        head + (f" {json.dumps(variant)}: SRA / CRA |" if variant else ""),
        "|---|---|---|---|---|---|---|" + ("---|" if variant else ""),
    ]
    for r in result["rows"]:
        line = (
            f"| {r['style']} | {r['example']} ({r['example_split']}) "
            f"| {r['sra']:.1%} ({r['sra_95'][0]:.0%}-{r['sra_95'][1]:.0%}) "
            f"| {r['cra']:.1%} ({r['cra_95'][0]:.0%}-{r['cra_95'][1]:.0%}) "
            f"| {r['input']['sra']:.0%} / {r['input']['cra']:.0%} | {r['tempo']:.2f} | {r['finetune_s']:.1f} |"
        )
        if variant:
            v = r["transfer_params"]
            line += (
                f" {v['sra']:.1%} ({v['sra_95'][0]:.0%}-{v['sra_95'][1]:.0%}) / "
                f"{v['cra']:.1%} ({v['cra_95'][0]:.0%}-{v['cra_95'][1]:.0%}) |"
            )
        lines.append(line)
    m = result["mean"]
    line = (
        f"| mean | | {m['sra']:.1%} (min {m['sra_min']:.1%}) | {m['cra']:.1%} "
        f"| {m['input_sra']:.0%} / {m['input_cra']:.0%} | | {m['finetune_s']:.1f} |"
    )
    if variant:
        line += (
            f" {m['transfer_params_sra']:.1%} (min {m['transfer_params_sra_min']:.1%}) / "
            f"{m['transfer_params_cra']:.1%} |"
        )
    lines.append(line)
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    from motionaug.augment.synth.styles import STYLES

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--synth-corpus", type=Path, required=True)
    parser.add_argument("--synth-base", type=Path, required=True)
    parser.add_argument("--bandai-corpus", type=Path, required=True)
    parser.add_argument("--bandai-base", type=Path, required=True)
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--direction", choices=("both", "bandai-to-synth", "synth-to-bandai"), default="both")
    parser.add_argument("--styles", default="", help="comma list: only these styles (of either corpus)")
    parser.add_argument("--n-content", type=int, default=36, help="synthetic test clips (bandai-to-synth)")
    parser.add_argument("--params", default="{}", help="JSON merged into the Bandai-2 config's method params")
    parser.add_argument(
        "--transfer-params",
        default="",
        help="JSON of transfer-time params (style_guidance, foot_lock): transfer again from the same fine-tunes",
    )
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument(
        "--transfer-only", action="store_true", help="fine-tune and transfer, keep the outputs, score nothing"
    )
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    os.environ["MOTIONAUG_TORCH_THREADS"] = str(args.threads)
    args.work.mkdir(parents=True, exist_ok=True)
    keep = set(filter(None, args.styles.split(",")))
    judges = None if args.transfer_only else (load_classifiers(args.synth_base), load_classifiers(args.bandai_base))
    bandai, params = bandai_styles(args.bandai_corpus)
    params = {**params, **json.loads(args.params)}
    transfer_params = json.loads(args.transfer_params) if args.transfer_params else None
    report: dict[str, Any] = {
        "args": {k: str(v) for k, v in vars(args).items()},
        "uptime_before": subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip(),
        "results": [],
    }
    if args.direction in ("both", "bandai-to-synth"):
        styles = [(s, e) for s, e in bandai if not keep or s.name in keep]
        content = round_robin(held_out(args.synth_corpus, SYNTH_NEUTRAL), args.n_content)
        report["results"].append(
            run_direction(
                "bandai-to-synth",
                styles,
                train_pool(args.synth_corpus, SYNTH_NEUTRAL),
                content,
                args.synth_corpus,
                args.synth_base,
                None if judges is None else (judges[1], judges[0]),
                params,
                transfer_params,
                args.work,
            )
        )
    if args.direction in ("both", "synth-to-bandai"):
        names = [s for s in STYLES if s != SYNTH_NEUTRAL and (not keep or s in keep)]
        content = held_out(args.bandai_corpus, BANDAI_NEUTRAL)
        report["results"].append(
            run_direction(
                "synth-to-bandai",
                synth_styles(args.synth_corpus, names),
                train_pool(args.bandai_corpus, BANDAI_NEUTRAL),
                content,
                args.bandai_corpus,
                args.bandai_base,
                judges,
                params,
                transfer_params,
                args.work,
            )
        )
    report["uptime_after"] = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    if judges is not None:
        (args.work / "across.json").write_text(json.dumps(report, indent=1) + "\n")
        print("\n\n".join(table(r) for r in report["results"]))
    return report


if __name__ == "__main__":
    main(sys.argv[1:])
