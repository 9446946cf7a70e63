"""Leave-style-out (LSO): styles the trained parts never saw, learnt from k examples, judged on held-out takes.

    python bench/bench_lso.py setup  --corpus runs/bandai2 --kind bandai2 --work WORK
    python bench/bench_lso.py run    --corpus runs/bandai2 --kind bandai2 --work WORK --fold fold1 --row ROW --split val
    python bench/bench_lso.py gather --kind bandai2 [--split test]

``setup`` fixes the example draws (3 per style, k = 1 and 3, train takes, disjoint) for every style of every fold
and fits the judges on the train split without any draw's takes; both are written before any row runs. A ``run``
unit is one (corpus, fold, row, split): the held-out ``normal`` takes of the split go into each of the fold's styles
for each draw and k, and the per-clip judge readings are written to ``bench/lso/`` (committed). Rows: ``content``
(the untouched clip), ``moments`` (the moment rule on the content clip, no network: the control of that step),
``shapers`` (``--shapers A,B`` on the content clip, in order, no network: a shaper's control, ``--hook-modules``
importing a lab one), ``foot_lock`` (on-the-fly's foot lock on the content clip, the control of that step),
``tempo`` (on-the-fly's retiming to the tempo its artefact measured, the control of that step; needs the onthefly
unit's run folders), and the methods through ``motionaug run`` with trained parts fitted on the corpus without the
fold's styles.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import torch

from motionaug.augment.corpus import Corpus
from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.corpus.style_sets import write_without_styles
from motionaug.augment.eval.judges import JUDGES, fit_judges, load_judges
from motionaug.augment.eval.numerics import pinned, pinned_env, pinned_kernels
from motionaug.augment.eval.protocol import (
    LSO_FOLDS,
    ExampleDraws,
    TrainView,
    blind,
    check_held_out,
    draw_examples,
    fold_of,
    guarded,
    take_of,
)
from motionaug.augment.io import atomic_save_npy, atomic_write_text
from motionaug.augment.methods.hooks import (
    HookSpec,
    import_hook_modules,
    output_shapers,
    parse_hook_specs,
)
from motionaug.augment.methods.shaping import nearest_root_motion, shape, write_shaping
from motionaug.augment.metrics import matched_fmd, mean_foot_skating
from motionaug.augment.motion.features import features_to_joints
from motionaug.augment.motion.foot_lock import lock_feet
from motionaug.augment.motion.tempo import retime
from motionaug.augment.outputs.shards import iter_shard_rows, row_motion
from motionaug.augment.synth import STYLE_WORDS
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.run_config import RunConfig, apply_overrides, load_run_config
from motionaug.schemas.skeleton import T2M
from motionaug.schemas.styles import StyleExample, StyleSpec, StyleWords
from motionaug.workflows.ray_executor import execute_run

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "bench" / "lso"
NEUTRAL = {"bandai2": "normal", "synthetic": "neutral"}
CONFIGS = {"bandai2": "bandai2-{method}.yaml", "synthetic": "{method}-synthetic.yaml"}
DRAWS, K_MAX = 3, 3
TEMPO_CAP = 196  # on-the-fly's prior's longest clip (its base models' max_frames): a slowed clip is cut there
CROSS_DRAWS = 2
CROSS_JUDGES = "cross-judges"  # the dataset-1 style judges' folder under --work and their summary under RESULTS
STYLE_JUDGES = ("style", "style_clip")
PINNED_COMMANDS = ("setup", "cross-setup")  # they fit the judges, under pinned numerics (augment/eval/numerics.py)
CROSS_WORDS = {  # Bandai dataset-1's styles that no Bandai-2 or synthetic style stands for, in caption words
    "happy": StyleWords(adjective="happy", adverb="happily", phrases=("in a happy way",)),
    "sad": StyleWords(adjective="sad", adverb="sadly", phrases=("in a sad way",)),
    "angry": StyleWords(adjective="angry", adverb="angrily", phrases=("in an angry way",)),
    "proud": StyleWords(adjective="proud", adverb="proudly", phrases=("in a proud way",)),
    "not-confident": StyleWords(adjective="unsure", adverb="unsurely", phrases=("without confidence",)),
    "musical": StyleWords(adjective="musical", adverb="rhythmically", phrases=("like a musical performer",)),
    "giant": StyleWords(adjective="giant", adverb="heavily", phrases=("like a giant",)),
    "chimpira": StyleWords(adjective="swaggering", adverb="swaggeringly", phrases=("like a street thug",)),
}


def commit() -> str:
    return subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True, text=True).stdout.strip()


def write_unit(name: str, result: dict[str, Any]) -> None:
    """A unit's results file under ``bench/lso/`` (compact JSON: it holds every per-clip reading)."""
    path = RESULTS / f"{name}.json"
    atomic_write_text(path, json.dumps(result, indent=None, separators=(",", ":")) + "\n")
    log(f"wrote {path}")


def log(message: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {message}", file=sys.stderr, flush=True)


def all_styles(kind: str) -> list[str]:
    return [s for fold in LSO_FOLDS[kind] for s in fold.held_out]


def draws_path(kind: str) -> Path:
    return RESULTS / f"{kind}-draws.json"


def read_draws(kind: str) -> ExampleDraws:
    return ExampleDraws.model_validate_json(draws_path(kind).read_text(encoding="utf-8"))


def examples_of(draws: ExampleDraws, style: str, draw: int, k: int) -> list[str]:
    """Draw ``draw``'s first ``k`` takes: the k = 1 example is the first of its k = 3 draw."""
    return draws.draws[style][draw][:k]


def train_clips(corpus: Path) -> dict[str, MotionClip]:
    return {c.id: c for c in Corpus(corpus, split="train")}


def scored_clips(corpus: Path, kind: str, split: str) -> list[MotionClip]:
    return [c for c in Corpus(corpus, split=split) if c.style == NEUTRAL[kind]]


# ---- setup: draws and judges, before any row ---------------------------------------------------------------


def setup(args: argparse.Namespace) -> None:
    RESULTS.mkdir(parents=True, exist_ok=True)
    scored = [c.id for split in ("val", "test") for c in Corpus(args.corpus, split=split)]
    view = TrainView(args.corpus, scored)
    if not draws_path(args.kind).is_file():
        draws = draw_examples(view, all_styles(args.kind), k=K_MAX, n_draws=DRAWS, seed=args.seed)
        draws.write(draws_path(args.kind))
        log(f"draws written to {draws_path(args.kind)}")
    draws = read_draws(args.kind)
    judges_dir = args.work / "judges"
    if not args.draws_only and not (judges_dir / "judges.json").is_file():
        train = [c for c in view if take_of(c.id) not in draws.takes()]
        held_out = list(Corpus(args.corpus, split="test"))
        log(f"fitting the judges on {len(train)} train clips ({len(draws.takes())} example takes left out)")
        torch.set_num_threads(args.threads)
        with pinned_kernels() as numerics:
            judges = fit_judges(train, judges_dir, epochs=args.judge_epochs, seed=args.seed, held_out=held_out)
        summary = {
            "commit": commit(),
            "train_clips": len(train),
            "epochs": args.judge_epochs,
            "threads": args.threads,  # the fit's float sums, hence its weights, depend on the thread count
            "numerics": numerics,  # and on the kernels: pinned, the same on every x86-64 CPU with AVX2
            "test_accuracy": judges.info.accuracy,
            "judges": judges.fingerprint,
        }
        atomic_write_text(RESULTS / f"{args.kind}-judges.json", json.dumps(summary, indent=1) + "\n")


# ---- rows ------------------------------------------------------------------------------------------------------

Transfers = dict[tuple[str, int, int], list[tuple[str, np.ndarray]]]
"""(style, draw, k) -> (source id, output features) of every transfer."""


def extra_takes(args: argparse.Namespace, styles: list[str]) -> dict[str, list[MotionClip]]:
    """``--extra-example``: each style's val takes of that content (empty when unset), takes no judge and no trained
    part saw and no row scores (only neutral takes are scored)."""
    if not args.extra_example:
        return {}
    scored = [c.id for c in scored_clips(args.corpus, args.kind, args.split)]
    val = [c for c in Corpus(args.corpus, split="val") if c.content == args.extra_example]
    takes: dict[str, list[MotionClip]] = {}
    for style in styles:
        found = sorted((c for c in val if c.style == style), key=lambda c: c.id)
        if not found:
            raise MotionDataError(f"--extra-example {args.extra_example}", f"no val take of style {style!r} has it")
        takes[style] = guarded(found, scored)
    return takes


def example_clips(
    draws: ExampleDraws,
    style: str,
    draw: int,
    k: int,
    originals: dict[str, MotionClip],
    extras: dict[str, list[MotionClip]],
) -> list[MotionClip]:
    """Draw ``draw``'s first k takes, then the scenario's added take of the style (``extra_takes``) where set."""
    examples = [originals[i] for i in examples_of(draws, style, draw, k)]
    if style in extras:
        examples.append(extras[style][draw % len(extras[style])])
    return examples


def reference_of(example: MotionClip, plain: dict[str, MotionClip], by: str) -> tuple[str, np.ndarray]:
    """An example's reference (id, motion): the plain train clip nearest by root motion (``root``, a run's rule when
    the user names none) or, among the plain clips of the example's own content, the one a user would name
    (``content``; the example's label is the user's knowledge, no scored clip's)."""
    alike = {i: c for i, c in plain.items() if by == "root" or c.content == example.content}
    return nearest_root_motion(example.motion, {i: c.motion for i, c in alike.items()})


def shaper_row(
    args: argparse.Namespace,
    fold_corpus: Path,
    draws: ExampleDraws,
    styles: list[str],
    originals: dict[str, MotionClip],
    shapers: list[HookSpec],
) -> Transfers:
    """Output shapers on each content clip, in order, no network (their control): the product's ``shape``, so each
    clip is shaped with the example its id and motion pick against that example's reference (``reference_of``),
    all in the corpus's features as a run's shapers read them; ``--extra-example`` adds one example per draw."""
    plain = {c.id: c for c in Corpus(fold_corpus, split="train") if c.style == NEUTRAL[args.kind]}
    steps = output_shapers.create_all(shapers)
    extras = extra_takes(args, styles)
    out: Transfers = {}
    for style in styles:
        for draw in range(len(draws.draws[style])):
            for k in args.k:
                examples = example_clips(draws, style, draw, k, originals, extras)
                references = [reference_of(e, plain, args.references)[1] for e in examples]
                motions = [e.motion for e in examples]
                out[(style, draw, k)] = [
                    (clip.id, shape(clip.motion, clip, steps, motions, references))
                    for clip in blind(scored_clips(args.corpus, args.kind, args.split))
                ]
    return out


def tempo_row(args: argparse.Namespace, styles: list[str]) -> Transfers:
    """On-the-fly's retiming on the content clip, no network (the control of that step): each clip played at the
    tempo the on-the-fly unit's artefact measured from the same examples, capped as the method caps it."""
    out: Transfers = {}
    for style in styles:
        for draw in range(DRAWS):
            for k in args.k:
                run = args.work / args.fold / f"onthefly-{args.split}-d{draw}-k{k}" / "styles" / style
                found = sorted(run.glob("**/artifact.json"))
                if not found:
                    raise MotionDataError(str(run), "no on-the-fly artefact: run the onthefly unit first")
                tempo = float(json.loads(found[0].read_text(encoding="utf-8"))["tempo"])
                out[(style, draw, k)] = [
                    (c.id, c.motion if tempo == 1.0 else retime(c.motion, tempo, max(len(c.motion), TEMPO_CAP)))
                    for c in blind(scored_clips(args.corpus, args.kind, args.split))
                ]
    return out


def style_spec(shipped: RunConfig, style: str) -> StyleSpec:
    """The shipped config's spec of ``style``, else (a synthetic style the config does not list) the synthetic
    corpus's own words for it, with a walk described in them."""
    for spec in shipped.styles:
        if spec.name == style:
            return spec
    words = STYLE_WORDS.get(style) or CROSS_WORDS[style]
    description = f"a person walks {words.adverb}" if words.adverb else f"a person walks {words.phrases[0]}"
    return StyleSpec(name=style, words=words, examples=[StyleExample(source="unused", description=description)])


def method_row(
    args: argparse.Namespace,
    fold_corpus: Path,
    draws: ExampleDraws,
    styles: list[str],
    originals: dict[str, MotionClip],
    tag: str = "",
) -> Transfers:
    """``motionaug run`` of the method's shipped config per (draw, k): trained parts fit on the fold corpus (no
    held-out style), examples given as files, content pool from the fold corpus's train split."""
    shipped = load_run_config(REPO / "configs" / CONFIGS[args.kind].format(method=args.row))
    example_dir = args.work / "examples"
    named = args.references == "content"  # else the run picks each reference by root motion
    plain = {c.id: c for c in Corpus(fold_corpus, split="train") if c.style == NEUTRAL[args.kind]} if named else {}
    extras = extra_takes(args, styles)
    out: Transfers = {}
    for draw in range(len(next(iter(draws.draws.values())))):
        for k in args.k:
            style_specs = []
            for style in styles:
                spec = style_spec(shipped, style)
                examples = example_clips(draws, style, draw, k, originals, extras)
                files = []
                for example in examples:
                    path = example_dir / f"{example.id}.npy"
                    if not path.is_file():
                        atomic_save_npy(path, example.motion)
                    files.append({"source": str(path), "description": spec.examples[0].description})
                    if named:
                        files[-1]["reference"] = reference_of(example, plain, "content")[0]
                style_specs.append({**spec.model_dump(mode="json"), "examples": files})
            data = json.loads(shipped.model_dump_json())
            data["styles"] = style_specs
            data["corpus"] |= {"path": str(fold_corpus), "split": args.split, "pool_split": "train"}
            data["corpus"]["filters"]["source_styles"] = [NEUTRAL[args.kind]]
            data["base_models"] |= {
                "path": str(args.work / args.fold / f"{args.row}-trained"),
                "corpus": str(fold_corpus),
                "pretrain_if_missing": True,  # on-the-fly's prior too is fitted on the fold corpus, never reused
            }
            data["output"] = str(args.work / args.fold / f"{tag}{row_name(args)}-{args.split}-d{draw}-k{k}")
            data["compute"] |= {"num_cpus": 2}
            data = apply_overrides(data, args.set)
            config = load_run_config(None, data=data)
            check_held_out(config)
            log(f"{args.row}: draw {draw}, k {k}")
            execute_run(config)
            for row in iter_shard_rows(config.output, columns=["source_id", "style", "motion", "n_frames", "n_feats"]):
                out.setdefault((row["style"], draw, k), []).append((row["source_id"], row_motion(row)))
    return out


def row_shapers(args: argparse.Namespace) -> list[HookSpec]:
    """A shapers row's chain: the moment rule for ``moments``, else ``--shapers`` (after ``--hook-modules``)."""
    import_hook_modules(args.hook_modules)
    return ["moments"] if args.row == "moments" else parse_hook_specs(args.shapers)


def row_name(args: argparse.Namespace) -> str:
    """The row as units and run folders name it: the method, plus ``--variant`` for a design tried on val."""
    return f"{args.row}+{args.variant}" if args.variant else args.row


def run(args: argparse.Namespace) -> None:
    fold = fold_of(args.kind, args.fold)
    draws = read_draws(args.kind)
    fold_corpus = args.work / args.fold / "corpus"
    if not (fold_corpus / "all.txt").is_file():
        write_without_styles(args.corpus, fold_corpus, list(fold.held_out))
    torch.set_num_threads(args.threads)
    start = time.perf_counter()
    styles = list(fold.held_out)
    if args.row in ("content", "foot_lock"):
        # foot_lock: on-the-fly's shipped post-process on the content clip, no network (its control row)
        sources = [
            (c.id, lock_feet(c.motion) if args.row == "foot_lock" else c.motion)
            for c in blind(scored_clips(args.corpus, args.kind, args.split))
        ]
        transfers = {(s, d, k): sources for s in styles for d in range(DRAWS) for k in args.k}
    elif args.row in ("moments", "shapers"):
        transfers = shaper_row(args, fold_corpus, draws, styles, train_clips(args.corpus), row_shapers(args))
    elif args.row == "tempo":
        transfers = tempo_row(args, styles)
    else:
        transfers = method_row(args, fold_corpus, draws, styles, train_clips(args.corpus))
    seconds = time.perf_counter() - start
    result = score(args, transfers) | {
        "commit": commit(),
        "corpus": args.kind,
        "fold": args.fold,
        "row": row_name(args),
        "split": args.split,
        "overrides": args.set,
        "shapers": args.shapers if args.row == "shapers" else None,
        "extra_example": args.extra_example,
        "references": args.references,
        "hook_modules": args.hook_modules,
        "k": args.k,
        "seed": args.seed,
        "seconds": round(seconds, 1),
    }
    write_unit(f"{args.kind}-{args.fold}-{row_name(args)}-{args.split}", result)


def step_time(args: argparse.Namespace) -> None:
    """The per-style step alone, timed: each fold style's ``prepare`` from draw 0's examples at every k, with the
    unit's trained parts and 64 plain train clips as the pool (the plan's pool size), then the output shapers'
    reference pick when the config has shapers, ``--threads`` threads."""
    from motionaug.augment.methods.registry import create_method

    shipped = load_run_config(REPO / "configs" / CONFIGS[args.kind].format(method=args.row))
    shipped = load_run_config(None, data=apply_overrides(json.loads(shipped.model_dump_json()), args.set))
    method = create_method(shipped.method.name, shipped.method.params)
    fold_corpus, trained = args.work / args.fold / "corpus", args.work / args.fold / f"{args.row}-trained"
    originals, draws = train_clips(args.corpus), read_draws(args.kind)
    pool = [c for c in Corpus(fold_corpus, split="train") if c.style == NEUTRAL[args.kind]][:64]
    torch.set_num_threads(args.threads)
    for style in fold_of(args.kind, args.fold).held_out:
        for k in args.k:
            examples = [originals[i] for i in examples_of(draws, style, 0, k)]
            out = args.work / args.fold / "step-time" / f"{args.row}-{style}-k{k}"
            start = time.perf_counter()
            method.prepare(style_spec(shipped, style), examples, trained, pool, out, seed=0)
            if shipped.method.shapers:  # the prepare stage's reference pick for the output shapers
                write_shaping(out, style, examples, pool, shipped.method.shapers)
            print(f"{args.row} {style} k={k}: {time.perf_counter() - start:.1f} s ({args.threads} threads)")


def fmd_or_none(a: np.ndarray, b: np.ndarray, seed: int) -> tuple[float | None, int]:
    """``matched_fmd``, or None where the covariances of so few clips have no real square root."""
    try:
        return matched_fmd(a, b, seed)
    except MotionDataError:
        return None, min(len(a), len(b))


def score(args: argparse.Namespace, transfers: Transfers) -> dict[str, Any]:
    """Per (style, draw, k): each judge's top-1 reading of every transfer, FMD against real held-out takes of the
    style (content judge 1's features, matched counts, as the earlier Bandai-2 figures), foot skating; and which
    judge fit read them (``Judges.fingerprint``)."""
    judges = load_judges(args.work / "judges")
    held = Corpus(args.corpus, split=args.split).by_style()
    train = Corpus(args.corpus, split="train").by_style()
    content_of = {c.id: c.content for c in Corpus(args.corpus, split=args.split)}
    units = []
    for (style, draw, k), outputs in sorted(transfers.items()):
        motions = [m for _, m in outputs]
        readings = {name: judges.predict(name, motions) for name in JUDGES}
        _, real_feats = judges.predict("content", [c.motion for c in held[style]])
        _, train_feats = judges.predict("content", [c.motion for c in train[style]])
        fmd, n = fmd_or_none(readings["content"][1], real_feats, args.seed)
        floor, _ = fmd_or_none(train_feats, real_feats, args.seed)
        units.append(
            {
                "style": style,
                "draw": draw,
                "k": k,
                "sources": [s for s, _ in outputs],
                "truth_content": [content_of[s] for s, _ in outputs],
                "read": {name: [judges.labels(name)[int(i)] for i in readings[name][0]] for name in JUDGES},
                "fmd": fmd,
                "fmd_floor": floor,
                "fmd_n": n,
                "skating": mean_foot_skating([features_to_joints(m) for m in motions], T2M, 20.0),
                "real_skating": mean_foot_skating([features_to_joints(c.motion) for c in held[style]], T2M, 20.0),
            }
        )
    return {"units": units, "judges": judges.fingerprint}


# ---- gather ----------------------------------------------------------------------------------------------------


def summary(result: dict[str, Any], k: int) -> dict[str, float]:
    """Means over the fold's styles and draws at ``k``: SRA per style judge, CRA per content judge, FMD / floor."""
    units = [u for u in result["units"] if u["k"] == k]
    out: dict[str, float] = {}
    for judge in ("style", "style_clip"):
        out[f"sra_{judge}"] = float(np.mean([np.mean([r == u["style"] for r in u["read"][judge]]) for u in units]))
    for judge in ("content", "content_pose"):
        out[f"cra_{judge}"] = float(
            np.mean([np.mean([r == t for r, t in zip(u["read"][judge], u["truth_content"])]) for u in units])
        )
    ratios = [u["fmd"] / u["fmd_floor"] for u in units if u["fmd"] is not None and u["fmd_floor"]]
    out["fmd_ratio"] = float(np.mean(ratios)) if ratios else float("nan")
    out["skating_ratio"] = float(np.mean([u["skating"] / max(u["real_skating"], 1e-9) for u in units]))
    per_style = defaultdict(list)
    for u in units:
        per_style[u["style"]].append(np.mean([r == u["style"] for r in u["read"]["style_clip"]]))
    out["worst_style_sra_style_clip"] = float(min(np.mean(v) for v in per_style.values()))
    return out


ROW_ORDER = ("content", "moments", "foot_lock", "tempo", "stats", "onthefly", "erd", "umsd")


def gather_wide(args: argparse.Namespace) -> None:
    """One line per row: each figure as ``k1/k3`` for fold 1, then for fold 2 (``-`` where a unit or k has not run)."""
    found: dict[str, dict[str, dict[str, Any]]] = defaultdict(dict)
    for path in sorted(RESULTS.glob(f"{args.kind}-fold*-*-{args.split}.json")):
        result = json.loads(path.read_text(encoding="utf-8"))
        found[result["row"]][result["fold"]] = result
    columns = [
        ("sra_style", "{:.1f}", 100),
        ("sra_style_clip", "{:.1f}", 100),
        ("cra_content", "{:.1f}", 100),
        ("cra_content_pose", "{:.1f}", 100),
        ("worst_style_sra_style_clip", "{:.0f}", 100),
        ("fmd_ratio", "{:.1f}", 1),
        ("skating_ratio", "{:.1f}", 1),
    ]
    head = ["row (fold 1 k1/k3; fold 2 k1/k3)", "SRA j1 %", "SRA j2 %", "CRA c1 %", "CRA c2 %", "worst j2 %"]
    print("| " + " | ".join([*head, "FMD/floor", "skate"]) + " |")
    print("|---|---|---|---|---|---|---|---|")
    for row in sorted(found, key=lambda r: ROW_ORDER.index(r) if r in ROW_ORDER else len(ROW_ORDER)):
        cells = []
        for key, fmt, scale in columns:
            folds = []
            for fold in ("fold1", "fold2"):
                result = found[row].get(fold)
                if result is None:
                    folds.append("-")
                    continue
                values = (fmt.format(summary(result, k)[key] * scale) if k in result["k"] else "-" for k in (1, 3))
                folds.append("/".join("100" if v == "100.0" else v for v in values))
            cells.append("; ".join(folds))
        print(f"| {row} | " + " | ".join(cells) + " |")
    print(judges_note({row: list(folds.values()) for row, folds in found.items()}))


def judges_note(rows: dict[str, list[dict[str, Any]]]) -> str:
    """Which judge fit scored each row (``Judges.fingerprint``; ``unrecorded`` for units written before units kept
    it): rows compare only under one fit, as a refit moves the same outputs' readings by several points."""
    by_fit: dict[str, list[str]] = defaultdict(list)
    for row, results in rows.items():
        for fit in sorted({result.get("judges") or "unrecorded" for result in results}):
            by_fit[fit].append(row)
    fits = "; ".join(f"{fit}: {', '.join(sorted(names))}" for fit, names in sorted(by_fit.items()))
    warning = " (several fits: compare rows under one fit only)" if len(by_fit) > 1 else ""
    return f"judges{warning}: {fits}"


def gather(args: argparse.Namespace) -> None:
    if args.wide:
        gather_wide(args)
        return
    rows: dict[str, list[dict[str, Any]]] = defaultdict(list)
    print("| fold | row | k | SRA j1 | SRA j2 | CRA c1 | CRA c2 | worst style j2 | FMD / floor | skating / real | s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for path in sorted(RESULTS.glob(f"{args.kind}-fold*-*-{args.split}.json")):
        result = json.loads(path.read_text(encoding="utf-8"))
        for k in result["k"]:
            s = summary(result, k)
            print(
                f"| {result['fold']} | {result['row']} | {k} | {s['sra_style']:.1%} | {s['sra_style_clip']:.1%} "
                f"| {s['cra_content']:.1%} | {s['cra_content_pose']:.1%} | {s['worst_style_sra_style_clip']:.1%} "
                f"| {s['fmd_ratio']:.2f} | {s['skating_ratio']:.2f} | {result['seconds']:.0f} |"
            )
        rows[result["row"]].append(result)
    print(judges_note(rows))


# ---- across datasets: dataset-1 styles no trained part has seen, on Bandai-2 test takes -------------------------


def cross_setup(args: argparse.Namespace) -> None:
    """Draws (2 per style, k = 1, a walk take first) from Bandai dataset-1, and a judge fitted on dataset-1 without
    the example takes, with its leave-one-content-out accuracy."""
    view = TrainView(args.novel, [], split="all")
    path = RESULTS / "cross-draws.json"
    if not path.is_file():
        draw_examples(view, list(CROSS_WORDS), k=1, n_draws=CROSS_DRAWS, seed=args.seed).write(path)
    draws = ExampleDraws.model_validate_json(path.read_text(encoding="utf-8"))
    clips = [c for c in view if take_of(c.id) not in draws.takes()]
    torch.set_num_threads(args.threads)
    loco: dict[str, dict[str, float]] = {}
    for content in sorted({c.content for c in clips if c.content}):
        log(f"cross judge without content {content}")
        train = [c for c in clips if c.content != content]
        folder = args.work / "cross-loco" / content
        with pinned_kernels():
            judges = fit_judges(train, folder, epochs=args.judge_epochs, seed=args.seed, which=STYLE_JUDGES)
        for name in ("style", "style_clip"):
            held = [c for c in clips if c.content == content and c.style in judges.labels(name)]
            read, _ = judges.predict(name, [c.motion for c in held])
            right = [judges.labels(name)[int(i)] == c.style for i, c in zip(read, held)]
            loco.setdefault(name, {})[content] = float(np.mean(right)) if right else float("nan")
    with pinned_kernels() as numerics:
        fit_judges(clips, args.work / args.judges, epochs=args.judge_epochs, seed=args.seed, which=STYLE_JUDGES)
    summary = {
        "commit": commit(),
        "train_clips": len(clips),
        "epochs": args.judge_epochs,
        "threads": args.threads,
        "numerics": numerics,
        "loco_accuracy": {name: float(np.nanmean(list(v.values()))) for name, v in loco.items()},
        "loco_by_content": loco,
    }
    atomic_write_text(RESULTS / f"{args.judges}.json", json.dumps(summary, indent=1) + "\n")


def cross_run(args: argparse.Namespace) -> None:
    """One row of the cross-dataset table: fold 1's trained parts (the method's, on the fold corpus), each dataset-1
    style learnt from its example, applied to the Bandai-2 ``normal`` takes of the split."""
    draws = ExampleDraws.model_validate_json((RESULTS / "cross-draws.json").read_text(encoding="utf-8"))
    fold_corpus = args.work / args.fold / "corpus"
    styles = list(CROSS_WORDS)
    novel = {c.id: c for c in Corpus(args.novel, split="all")}
    start = time.perf_counter()
    args.k = [1]
    if args.row == "content":
        sources = blind(scored_clips(args.corpus, args.kind, args.split))
        transfers = {(s, d, 1): [(c.id, c.motion) for c in sources] for s in styles for d in range(CROSS_DRAWS)}
    elif args.row in ("moments", "shapers"):
        transfers = shaper_row(args, fold_corpus, draws, styles, novel, row_shapers(args))
    else:
        transfers = method_row(args, fold_corpus, draws, styles, novel, tag="cross-")
    seconds = time.perf_counter() - start
    style_judges = load_judges(args.work / args.judges)
    content_judges = load_judges(args.work / "judges")
    content_of = {c.id: c.content for c in Corpus(args.corpus, split=args.split)}
    units = []
    for (style, draw, k), outputs in sorted(transfers.items()):
        motions = [m for _, m in outputs]
        read = {n: style_judges.predict(n, motions)[0] for n in ("style", "style_clip")}
        read |= {n: content_judges.predict(n, motions)[0] for n in ("content", "content_pose")}
        units.append(
            {
                "style": style,
                "draw": draw,
                "k": k,
                "sources": [src for src, _ in outputs],
                "truth_content": [content_of[src] for src, _ in outputs],
                "read": {
                    n: [(style_judges if n.startswith("style") else content_judges).labels(n)[int(i)] for i in r]
                    for n, r in read.items()
                },
                "skating": mean_foot_skating([features_to_joints(m) for m in motions], T2M, 20.0),
            }
        )
    result = {
        "units": units,
        "commit": commit(),
        "row": row_name(args),
        "fold": args.fold,
        "split": args.split,
        "shapers": args.shapers if args.row == "shapers" else None,
        "judges": args.judges,
        "fingerprints": {"style": style_judges.fingerprint, "content": content_judges.fingerprint},
        "seconds": round(seconds, 1),
    }
    write_unit(f"cross-{args.fold}-{row_name(args)}-{args.split}{judges_suffix(args)}", result)


def judges_suffix(args: argparse.Namespace) -> str:
    """The cross units' file name tail: none for the first fit of the dataset-1 judges, else their name (a refit
    reads differently on 175 clips, so its units are gathered apart)."""
    return "" if args.judges == CROSS_JUDGES else f"-{args.judges}"


def cross_rate(units: list[dict[str, Any]], judge: str, walk_run: bool = False) -> float:
    """Top-1 SRA of ``judge`` over every transfer, or over those of walk and run takes only."""
    hits = [
        r == u["style"]
        for u in units
        for r, t in zip(u["read"][judge], u["truth_content"])
        if not walk_run or t in ("walk", "run")
    ]
    return float(np.mean(hits))


def cross_gather(args: argparse.Namespace) -> None:
    judges = json.loads((RESULTS / f"{args.judges}.json").read_text(encoding="utf-8"))
    loco = judges["loco_accuracy"]
    print(
        f"judge on dataset-1 ({judges['train_clips']} clips): leave-one-content-out accuracy "
        f"j1 {loco['style']:.1%}, j2 {loco['style_clip']:.1%}"
    )
    print("| row | SRA j1 | SRA j2 | SRA j1 walk/run | SRA j2 walk/run | CRA c1 | CRA c2 | most read (j1) | s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for path in sorted(RESULTS.glob(f"cross-fold*-*-{args.split}{judges_suffix(args)}.json")):
        result = json.loads(path.read_text(encoding="utf-8"))
        units = result["units"]

        cra = {
            n: float(np.mean([r == t for u in units for r, t in zip(u["read"][n], u["truth_content"])]))
            for n in ("content", "content_pose")
        }
        read = defaultdict(int)
        for u in units:
            for r in u["read"]["style"]:
                read[r] += 1
        top = max(read, key=read.__getitem__)
        share = read[top] / sum(read.values())
        print(
            f"| {result['row']} | {cross_rate(units, 'style'):.1%} | {cross_rate(units, 'style_clip'):.1%} "
            f"| {cross_rate(units, 'style', True):.1%} | {cross_rate(units, 'style_clip', True):.1%} "
            f"| {cra['content']:.1%} | {cra['content_pose']:.1%} "
            f"| {top} {share:.0%} | {result['seconds']:.0f} |"
        )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    commands_ = ["setup", "run", "gather", "step-time", "cross-setup", "cross", "cross-gather"]
    parser.add_argument("command", choices=commands_)
    parser.add_argument("--corpus", type=Path)
    parser.add_argument("--novel", type=Path, help="cross: the Bandai dataset-1 corpus (import-bvh, no split)")
    parser.add_argument("--kind", choices=sorted(LSO_FOLDS), default="bandai2")
    parser.add_argument("--work", type=Path)
    parser.add_argument("--fold", default="fold1")
    parser.add_argument("--row", default="content")
    parser.add_argument("--split", choices=["val", "test"], default="val")
    parser.add_argument("--k", type=int, nargs="+", default=[1, 3])
    parser.add_argument("--set", action="append", default=[], help="run: KEY=VALUE on the shipped config (a variant)")
    parser.add_argument(
        "--shapers",
        default="",
        help="run --row shapers: output shapers on the content clip, in order (NAME or NAME:KEY=VALUE:...)",
    )
    parser.add_argument("--hook-modules", nargs="*", default=[], help="run: modules registering hooks (lab.NAME)")
    parser.add_argument("--extra-example", default=None, help="run: add each style's val take of this content")
    parser.add_argument("--references", choices=["root", "content"], default="root", help="run: examples' references")
    parser.add_argument("--variant", default="", help="run: the variant's name, in the row and unit file names")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--judge-epochs", type=int, default=40)
    parser.add_argument("--judges", default=CROSS_JUDGES, help="cross*: the dataset-1 judges' name (a refit's)")
    parser.add_argument("--wide", action="store_true", help="gather: one line per row, both folds, k = 1 and 3")
    parser.add_argument("--draws-only", action="store_true", help="setup: fix the example draws, fit no judges yet")
    args = parser.parse_args(argv)
    if args.command in PINNED_COMMANDS and not pinned():
        # the judges' fit runs under pinned numerics, which act from a process's start: run again in a fresh one
        again = [sys.executable, str(Path(__file__).resolve()), *(sys.argv[1:] if argv is None else argv)]
        raise SystemExit(subprocess.run(again, env=pinned_env()).returncode)
    commands = {"setup": setup, "run": run, "gather": gather, "step-time": step_time}
    commands |= {"cross-setup": cross_setup, "cross": cross_run, "cross-gather": cross_gather}
    commands[args.command](args)


if __name__ == "__main__":
    main()
