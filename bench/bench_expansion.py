"""Does the expansion help a text-to-motion model? Issue 22's protocol, one command per corpus.

Usage: python bench/bench_expansion.py synthetic --work WORK [--methods stats,onthefly] [--prior-steps 1500]
       python bench/bench_expansion.py bandai2 --work WORK [--methods stats,onthefly]

Stages, each reused from WORK when finished (rerun the same command to resume):
1. corpus: ``synthetic``: a 1,000-clip synthetic corpus (every style, seed 0); ``bandai2``: ``motionaug corpus
   import-bvh`` of ../shared/data/bandai/dataset-2 with whole takes held out (docs/bandai.md).
2. judge: evaluators trained apart from A, B and C: ``synthetic``: base models (content / style classifiers, motion
   encoder) pre-trained on a second synthetic corpus (seed 1, every style); ``bandai2``: on the corpus's train split
   (every style; no second real corpus exists, so C's extra takes are among the judge's training data).
3. split (``motionaug.augment.eval.expansion.split_by_style``): A = the corpus without the missing styles (motions and
   captions); held out = the test split, every style; one train clip of ``walk`` per missing style as the example.
4. prior A: the same pre-training config for every training set (``--prior-steps``, seed 0), smaller than a
   method's own base models so that the comparison of A, B and C stays affordable.
   The methods' base models (``--method-base``): ``own`` (default): ``motionaug pretrain``'s defaults (``--size``)
   on A's corpus, ``priors/A_method``, as a user would expand with the base models made from their corpus;
   ``A``: prior A itself (its 400-step motion encoder gives the on-the-fly semantic loss little to go on).
5. per method: ``motionaug run`` stylizes A's ``expand`` clips (neutral train clips) into every missing style,
   their stylized clips are merged with A in its train split (B), prior B.
6. C: A plus the true stylized clips (synthetic: the ``expand`` clips re-rendered in each missing style; bandai2:
   the real train takes of the missing styles), prior C. ``--added-share S``: B's and C's priors draw S of their
   clips from the added ones (the merged corpus's ``added.txt``) and the rest from A's clips, whose share uniform
   draws would dilute by the number of added styles; A's prior is the same either way.
7. scoring (``score_prior``): every caption of every held-out clip, ``--samples`` times, DDIM-``--ddim`` with
   guidance ``--guidance``, judged by the judge. Writes WORK/results.json, prints a Markdown table; ``--plots DIR``
   writes the PNGs.

``--fold fold1`` runs the protocol under the leave-style-out rule (issue 41, item 5; docs/expansion.md): A lacks the
fold's styles (``augment.eval.protocol.LSO_FOLDS``); on ``bandai2`` their train takes are split in two halves by take
id (``judge_half``): C adds one, the examples (one ``walk`` take per style, k = 1) come from it, and the judge trains
on A's train split plus the other. Each method runs with its shipped config's settings (``configs/``), the base models
it reads fitted on A alone, its pools from A's train split.

``--prior-seeds 0,1,2`` pre-trains A, B and C once per seed (the methods' own data and base models stay seed 0's)
and reports the means, with each seed's figures and the spread in results.json: a single prior's recognition on
~100 captions moves by more than the 3-point content target with its seed or thread count.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.eval.evaluation import classify
from motionaug.augment.eval.expansion import (
    BASE_DIR,
    HELD_OUT_DIR,
    SPLIT_JSON,
    Judge,
    StyleSplit,
    gain_share,
    judge_clips,
    mean_figures,
    merge_clips,
    run_clips,
    score_prior,
    split_by_style,
    true_stylized,
)
from motionaug.augment.eval.protocol import fold_of
from motionaug.augment.io import atomic_save_npy
from motionaug.augment.methods.hooks import output_shapers
from motionaug.augment.methods.shaping import SHAPING_FILE, nearest_root_motion, read_shaping, shape
from motionaug.augment.motion.features import features_to_joints
from motionaug.augment.motion.foot_lock import lock_feet
from motionaug.augment.motion.tempo import retime
from motionaug.augment.training.data import read_clips, split_ids
from motionaug.augment.training.pretrain import PretrainConfig, ensure_base_models
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.run_config import load_run_config

REPO = Path(__file__).resolve().parents[1]
BANDAI2 = REPO.parent / "shared" / "data" / "bandai" / "dataset-2"
SYNTH_MISSING = ("angry", "old", "sneaky", "strutting")
CONFIGS = {"bandai2": "bandai2-{method}.yaml", "synthetic": "{method}-synthetic.yaml"}  # the shipped settings


TEMPO_CAP = 196  # on-the-fly's prior's longest clip (its base models' max_frames): a slowed clip is cut there


def log(message: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {message}", file=sys.stderr, flush=True)


def timed(work: Path, name: str, fn: Any) -> Any:
    """Run a stage and add its wall seconds to WORK/timings.json (a resumed stage adds its remainder)."""
    start = time.perf_counter()
    result = fn()
    path = work / "timings.json"
    timings = json.loads(path.read_text()) if path.is_file() else {}
    timings[name] = round(timings.get(name, 0.0) + time.perf_counter() - start, 1)
    tmp = path.with_name(f".{path.name}.{os.getpid()}")
    tmp.write_text(json.dumps(timings, indent=1))
    os.replace(tmp, path)  # two runs on one WORK (other --prior-seeds) never read a half-written file
    return result


def prior_config(args: argparse.Namespace, seed: int = 0) -> PretrainConfig:
    """The one pre-training config of A, B and C. Their own evaluators judge nothing here (the judge does), so they
    get the tiny classifier; A's motion encoder is what the on-the-fly method's L_s reads."""
    return PretrainConfig.for_size(
        args.size,
        seed=seed,
        prior_steps=args.prior_steps,
        encoder_steps=args.encoder_steps,
        classifier_size="tiny",
        classifier_epochs=args.classifier_epochs,
        added_share=args.added_share,
        threads=args.threads,
    )


def method_base(args: argparse.Namespace) -> str:
    """The priors/ folder whose base models the methods fine-tune or read (see ``--method-base``)."""
    return "A_method" if args.method_base == "own" else "A"


def method_base_config(args: argparse.Namespace) -> PretrainConfig:
    """``motionaug pretrain``'s defaults at ``--size``: the base models a user would expand with."""
    return PretrainConfig.for_size(
        args.size, seed=0, classifier_size="tiny", classifier_epochs=args.classifier_epochs, threads=args.threads
    )


def judge_config(args: argparse.Namespace) -> PretrainConfig:
    """The judge's prior only feeds its motion encoder's input layer, so it gets few steps; the encoder gets more."""
    return PretrainConfig.for_size(
        args.size,
        seed=1,
        prior_steps=args.judge_prior_steps,
        encoder_steps=args.judge_encoder_steps,
        classifier_epochs=args.judge_classifier_epochs,
        threads=args.threads,
    )


def make_corpora(args: argparse.Namespace, work: Path) -> tuple[Path, Path]:
    """The labelled corpus to split and the one the judge trains on."""
    corpus = work / "corpus"
    if args.protocol == "synthetic":
        from motionaug.augment.synth import generate_corpus

        if not (corpus / "labels.jsonl").is_file():
            timed(work, "corpus", lambda: generate_corpus(corpus, args.clips, seed=0))
        judge_corpus = work / "judge_corpus"
        if not (judge_corpus / "labels.jsonl").is_file():
            timed(work, "judge_corpus", lambda: generate_corpus(judge_corpus, args.clips, seed=1))
        return corpus, judge_corpus
    if not (corpus / "labels.jsonl").is_file():
        cmd = [*motionaug(), "corpus", "import-bvh", str(BANDAI2), "--out", str(corpus), "--max-frames", "196"]
        cmd += ["--val-takes", "3", "--test-takes", "3", "--mean-std"]
        timed(work, "corpus", lambda: subprocess.run(cmd, check=True))
    return corpus, corpus


def motionaug() -> list[str]:
    return [sys.executable, "-m", "motionaug.workflows.cli"]


def style_words(args: argparse.Namespace) -> dict[str, Any]:
    """How captions name each style: the synthetic lexicon, or Bandai-2's words from its shipped run config."""
    if args.protocol == "synthetic":
        from motionaug.augment.synth import STYLE_WORDS

        return dict(STYLE_WORDS)
    return {s.name: s.words for s in load_run_config(REPO / "configs" / "bandai2-onthefly.yaml").styles}


def missing_styles(args: argparse.Namespace) -> list[str]:
    if args.fold:
        return list(fold_of(args.protocol, args.fold).held_out)
    if args.missing:
        return args.missing.split(",")
    return list(SYNTH_MISSING) if args.protocol == "synthetic" else [s for s in style_words(args) if s != "normal"]


def description(example: dict[str, str], words: Any) -> str:
    """The example's caption when it names the style in the run's words, else a walk described with them (a
    Bandai caption may say "energetic" where the run's words for `active` are "in a lively manner")."""
    terms = [t for t in (words.adjective, words.adverb, *words.phrases) if t]
    if any(t in example["description"] for t in terms):
        return example["description"]
    return f"a person walks forward {words.phrases[0] if words.phrases else words.adverb}"


def method_of(label: str) -> str:
    """``onthefly-strong`` -> ``onthefly``: a label names one B (its folders and figures); the part before the first
    dash is the method, ``--params`` are looked up by the label, then by the method."""
    return label.split("-")[0]


def run_config(args: argparse.Namespace, work: Path, split: StyleSplit, method: str) -> dict[str, Any]:
    """A ``motionaug run`` config that stylizes A's ``expand`` clips into every missing style from one example each."""
    words = style_words(args)
    styles = [
        {
            "name": style,
            "words": words[style].model_dump(exclude_none=True, mode="json"),
            "examples": [{"source": str(work / "split" / ex["path"]), "description": description(ex, words[style])}],
        }
        for style, ex in split.examples.items()
    ]
    extra = dict(pair.split(":", 1) for pair in args.extra_example.split(",") if pair).get(method)
    if extra:  # read A's train clips and C's half once for every style
        base = work / "split" / BASE_DIR
        plain = [c for c in read_clips(base, split_ids(base, "train")) if c.style == split.neutral]
        added = list(true_stylized(work / "split", mode="corpus"))
        for spec in styles:
            spec["examples"] = extra_examples(args, work, split, spec["name"], spec["examples"][0], extra, plain, added)
    base_models: dict[str, Any] = {"path": str(work / "priors" / method_base(args)), "pretrain_if_missing": False}
    # erd and umsd train their network in the run, on a labelled style corpus whose train split holds no held-out clip
    # (under --fold: A itself, which lacks the missing styles too)
    if method_of(method) in ("erd", "umsd"):
        corpus = work / "split" / BASE_DIR if args.fold else work / "corpus"
        base_models = {"path": str(work / "networks" / method), "corpus": str(corpus)}
    source: dict[str, Any] = {"path": str(work / "split" / BASE_DIR), "split": "expand", "filters": {"max_frames": 199}}
    if args.fold:  # as an LSO unit: pools of A's neutral train clips (the shipped configs' source filter)
        source |= {"pool_split": "train", "filters": {"max_frames": 199, "source_styles": [split.neutral]}}
    return {
        "version": 1,
        "corpus": source,
        "styles": styles,
        "method": method_section(args, method),
        "base_models": base_models,
        "fan_out": {"per_clip": "all", "seed": 0},
        "compute": {"num_cpus": args.threads, "batch_size": 32, "unit_size": 256},
        "output": str(work / "runs" / method),
        "seed": 0,
    }


def extra_examples(
    args: argparse.Namespace,
    work: Path,
    split: StyleSplit,
    style: str,
    first: dict[str, str],
    content: str,
    plain: list[MotionClip],
    added: list[MotionClip],
) -> list[dict[str, str]]:
    """``--extra-example LABEL:CONTENT``: the style's example plus its first take of CONTENT in C's half (never the
    judge's), each naming as its reference A's plain train clip of its own content nearest by root motion, as the
    shipped configs do (bench/RESULTS.md 0, ``B2w``): a clip is then shaped by the example that moves as it does."""
    own = {c.id: c for c in added if c.style == style}
    taken = sorted(i for i, c in own.items() if c.content == content)
    if not taken:
        raise MotionDataError(f"--extra-example {content}", f"C's half holds no take of style {style!r}")
    walk, extra = own[split.examples[style]["id"]], own[taken[0]]
    path = work / "extra-examples" / f"{extra.id}.npy"
    if not path.is_file():
        atomic_save_npy(path, extra.motion)
    words = style_words(args)[style]
    texts = [description({"description": cap.text}, words) for cap in extra.captions]
    second = {
        "source": str(path),
        "description": next((t for t, c in zip(texts, extra.captions) if t == c.text), texts[0]),
    }
    examples = [dict(first), second]
    for example, clip in zip(examples, (walk, extra)):
        alike = {c.id: c.motion for c in plain if c.content == clip.content}
        example["reference"] = nearest_root_motion(clip.motion, alike)[0]
    return examples


def method_section(args: argparse.Namespace, label: str) -> dict[str, Any]:
    """The run's ``method``: under ``--fold`` the shipped config's (its settings and output steps, as an LSO unit
    runs it) with ``--params`` laid over them; otherwise the method's defaults with ``--params``."""
    section: dict[str, Any] = {"name": method_of(label), "params": {}}
    if args.fold:
        name = CONFIGS[args.protocol].format(method=method_of(label))
        section = load_run_config(REPO / "configs" / name).model_dump(mode="json")["method"]
    section["params"] = {**section.get("params", {}), **params_of(args, label)}
    return section


def params_of(args: argparse.Namespace, label: str) -> dict[str, Any]:
    params = json.loads(args.params)
    return params.get(label, params.get(method_of(label), {}))


def expand(args: argparse.Namespace, work: Path, split: StyleSplit, method: str) -> Path:
    """B for one method: run, export, return the merged corpus."""
    out = work / "corpora" / f"B_{method}"
    if (out / "Mean.npy").is_file():
        return out
    config_path = work / "runs" / f"{method}.yaml"
    config_path.parent.mkdir(parents=True, exist_ok=True)
    config_path.write_text(yaml.safe_dump(run_config(args, work, split, method), sort_keys=False))
    run_dir = work / "runs" / method
    log(f"expanding A with {method}")
    cmd = [*motionaug(), "run", str(config_path), "--out", str(run_dir)]
    timed(
        work,
        f"run_{method}",
        lambda: subprocess.run(cmd, check=True, env={**os.environ, "RAY_USAGE_STATS_ENABLED": "0"}),
    )
    timed(work, f"merge_{method}", lambda: merge_clips(work / "split" / BASE_DIR, run_clips(run_dir), out))
    return out


def control(work: Path, method: str) -> Path:
    """The control of ``method``'s output steps (issue 41: every post-process gets its row): A plus, for each clip
    the method's run added, its source clip through the same steps with no network, under the same id and caption.
    On-the-fly's steps are its retiming to the tempo its artefact measured (capped as the LSO ``tempo`` row caps
    it) and its foot lock; a run's output shapers (``method.shapers``) shape the source with the example and
    reference its prepare stage stored, as the transfer shapes an output; a method without such steps adds its
    sources untouched."""
    out = work / "corpora" / f"B_{method}_control"
    if (out / "Mean.npy").is_file():
        return out
    run_dir, base = work / "runs" / method, work / "split" / BASE_DIR
    config = load_run_config(work / "runs" / f"{method}.yaml")
    params, shapers = config.method.params, output_shapers.create_all(config.method.shapers)
    tempos: dict[str, float] = {}
    for path in sorted(run_dir.glob("styles/*/**/artifact.json")):
        style = path.relative_to(run_dir / "styles").parts[0]
        tempos.setdefault(style, float(json.loads(path.read_text(encoding="utf-8")).get("tempo", 1.0)))
    shaping: dict[str, tuple[list[np.ndarray], list[np.ndarray]]] = {}
    for path in sorted(run_dir.glob(f"styles/*/**/{SHAPING_FILE}")) if shapers else []:
        shaping.setdefault(path.relative_to(run_dir / "styles").parts[0], read_shaping(path.parent))

    def steps(clip: MotionClip) -> MotionClip:
        source_id = clip.meta["source_id"]
        motion = np.load(base / "new_joint_vecs" / f"{source_id}.npy")
        tempo = tempos.get(clip.style or "", 1.0)
        if tempo != 1.0:
            motion = retime(motion, tempo, max(len(motion), TEMPO_CAP))
        if params.get("foot_lock", False):
            motion = lock_feet(motion)
        if shapers:
            source = replace(clip, id=source_id, motion=motion.astype(np.float32))
            motion = shape(motion, source, shapers, *shaping[clip.style or ""])
        return replace(clip, motion=motion.astype(np.float32), meta={**clip.meta, "method": f"{method} control"})

    log(f"writing B_{method}_control ({method}'s output steps on its sources: tempos {tempos}, shaped {list(shaping)})")
    timed(work, f"corpus_{method}_control", lambda: merge_clips(base, map(steps, run_clips(run_dir)), out))
    return out


def upper_bound(work: Path) -> Path:
    out = work / "corpora" / "C"
    if not (out / "Mean.npy").is_file():
        log("writing C (A + the true stylized clips)")
        timed(work, "corpus_C", lambda: merge_clips(work / "split" / BASE_DIR, true_stylized(work / "split"), out))
    return out


def seeded(name: str, seed: int) -> str:
    """The priors/ and scores/ name of training set ``name``'s prior trained with ``seed`` (seed 0: the name)."""
    return name if seed == 0 else f"{name}-s{seed}"


def pretrain(args: argparse.Namespace, work: Path, name: str, corpus: Path, config: PretrainConfig) -> Path:
    log(f"pre-training {name} on {corpus.name} ({config.prior_steps} prior steps)")
    return timed(work, f"pretrain_{name}", lambda: ensure_base_models(corpus, work / "priors" / name, config=config))


def train_and_score(
    args: argparse.Namespace, work: Path, name: str, corpus: Path, judge: Judge, split: StyleSplit
) -> dict[str, Any]:
    """Training set ``name``: one prior per ``--prior-seeds`` seed, each scored; the mean and each seed's figures."""
    runs = []
    for seed in args.prior_seeds:
        pretrain(args, work, seeded(name, seed), corpus, prior_config(args, seed))
        figures = score(args, work, seeded(name, seed), judge, split)
        if args.neutral_samples:
            figures["neutral_precise"] = score(args, work, seeded(name, seed), judge, split, neutral_only=True)
        runs.append(figures)
    return {"mean": mean_figures(runs), "seeds": dict(zip(map(str, args.prior_seeds), runs))}


def score(
    args: argparse.Namespace, work: Path, name: str, judge: Judge, split: StyleSplit, neutral_only: bool = False
) -> dict:
    """``score_prior``'s figures, or with ``neutral_only`` the neutral group's, each caption ``--neutral-samples``
    times: the content target's figure, measured on enough samples to be read to a point."""
    samples = args.neutral_samples if neutral_only else args.samples
    scored = f"{name}-neutral" if neutral_only else name
    scored = scored if samples == 1 else f"{scored}-x{samples}"
    path = work / "scores" / f"{scored}.json"
    if path.is_file():
        return json.loads(path.read_text())
    log(f"scoring {scored}")
    figures = timed(
        work,
        f"score_{scored}",
        lambda: score_prior(
            work / "priors" / name,
            work / "split" / HELD_OUT_DIR,
            judge,
            split.missing,
            neutral=split.neutral,
            guidance=args.guidance,
            steps=args.ddim,
            seed=args.seed,
            samples=samples,
            groups=["neutral"] if neutral_only else None,
        ),
    )
    figures = figures["neutral"] if neutral_only else figures
    path.parent.mkdir(exist_ok=True)
    path.write_text(json.dumps(figures, indent=1))
    return figures


def added_recognition(work: Path, judge: Judge, name: str) -> dict[str, Any]:
    """The judge's style and content recognition of the clips a training set adds to A (B: a method's stylized
    clips; C: the true ones): how much style the prior was given to learn, before any prior is trained."""
    corpus, base = work / "corpora" / name, work / "split" / BASE_DIR
    ids = sorted(set((corpus / "train.txt").read_text().split()) - set((base / "train.txt").read_text().split()))
    labels = {row["id"]: row for row in map(json.loads, (corpus / "labels.jsonl").read_text().splitlines())}
    joints = [features_to_joints(np.load(corpus / "new_joint_vecs" / f"{i}.npy")) for i in ids]
    out: dict[str, Any] = {"clips": len(ids)}
    for kind, model, names in (
        ("style", judge.classifiers.style, judge.classifiers.style_labels),
        ("content", judge.classifiers.content, judge.classifiers.content_labels),
    ):
        predicted = [names[int(k)] for k in classify(model, joints)[0].argmax(1)]
        out[kind] = float(np.mean([p == labels[i][kind] for p, i in zip(predicted, ids)])) if ids else None
    return out


def neutral_of(figures: dict[str, Any]) -> dict[str, Any]:
    """The neutral captions' figures the content target reads: ``--neutral-samples``' when scored."""
    return figures.get("neutral_precise") or figures["neutral"]


def spread(by_seed: dict[str, dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Per training set, the two target figures' standard deviation over prior seeds, in points."""
    out = {}
    for name, runs in by_seed.items():
        style = [r["style_prompted"]["style"] for r in runs["seeds"].values()]
        content = [neutral_of(r)["content"] for r in runs["seeds"].values()]
        out[name] = {
            "style_sd_points": 100 * float(np.std(style)),
            "neutral_content_sd_points": 100 * float(np.std(content)),
        }
    return out


def paired_gains(by_seed: dict[str, dict[str, Any]], name: str) -> dict[str, Any]:
    """B - A per prior seed both were trained with (style on style-prompted captions, neutral content), in points:
    the seed-paired differences whose mean the targets read, and their spread."""
    a, b = by_seed["A"]["seeds"], by_seed[name]["seeds"]
    seeds = [s for s in b if s in a]
    style = [100 * (b[s]["style_prompted"]["style"] - a[s]["style_prompted"]["style"]) for s in seeds]
    content = [100 * (neutral_of(b[s])["content"] - neutral_of(a[s])["content"]) for s in seeds]
    return {
        "seeds": seeds,
        "style": style,
        "content": content,
        "style_sd": float(np.std(style)),
        "content_sd": float(np.std(content)),
    }


def summarise(scores: dict[str, dict], methods: list[str], by_seed: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """Per method: B's gain over A as a share of C's, and the issue's targets (on the means over prior seeds, which
    equal the seed-paired means where A and B share their seeds)."""
    a, c = scores["A"], scores["C"]
    out: dict[str, Any] = {}
    for method in methods:
        b = scores[f"B_{method}"]
        sra = [s["style_prompted"]["style"] for s in (a, b, c)]
        out[method] = {
            "paired_by_seed": paired_gains(by_seed, f"B_{method}"),
            "style_gain_points": 100 * (sra[1] - sra[0]),
            "style_share_of_C": gain_share(*sra),
            "neutral_content_drop_points": 100 * (neutral_of(a)["content"] - neutral_of(b)["content"]),
            "C_neutral_content_drop_points": 100 * (neutral_of(a)["content"] - neutral_of(c)["content"]),
            "neutral_samples": neutral_of(b)["samples"],
            "targets_met": {
                "style >= A + 40 points": sra[1] - sra[0] >= 0.40,
                "style >= 70% of the way to C": (gain_share(*sra) or 0.0) >= 0.70,
                "neutral content <= 3 points below A": neutral_of(a)["content"] - neutral_of(b)["content"] <= 0.03,
            },
        }
    return out


def pct(value: float | None) -> str:
    return "n/a" if value is None else f"{100 * value:.1f}"


def num(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.2f}"


def table(scores: dict[str, dict]) -> str:
    """Markdown: one row per training set."""
    head = (
        "| training set | style-prompted: style % | content % | FMD | R@1 | R@3 | diversity "
        "| neutral: content % | style % | FMD | all captions: content % | R@1 | R@3 |"
    )
    lines = [head, "|" + "---|" * 13]
    for name, s in scores.items():
        p, n, a = s["style_prompted"], s["neutral"], s["all"]
        lines.append(
            f"| {name} | {pct(p['style'])} | {pct(p['content'])} | {num(p['fmd'])} | {pct(p['r1'])} | {pct(p['r3'])} "
            f"| {num(p['diversity'])} | {pct(neutral_of(s)['content'])} | {pct(n['style'])} | {num(n['fmd'])} "
            f"| {pct(a['content'])} | {pct(a['r1'])} | {pct(a['r3'])} |"
        )
    real = next(iter(scores.values()))
    lines.append(
        f"| real held-out clips | {pct(real['style_prompted']['real_style'])} "
        f"| {pct(real['style_prompted']['real_content'])} | | | | | {pct(real['neutral']['real_content'])} "
        f"| {pct(real['neutral']['real_style'])} | | {pct(real['all']['real_content'])} | | |"
    )
    return "\n".join(lines)


def plot(scores: dict[str, dict], out: Path, title: str) -> list[Path]:
    """Bar charts (matplotlib): recognition per caption group, and FMD / R@3 on style-prompted captions."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    names = list(scores)
    colours = ["#999999" if n == "A" else "#2b6cb0" if n.startswith("B") else "#2f855a" for n in names]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    panels = (
        ("style recognition, style-prompted captions (%)", [scores[n]["style_prompted"]["style"] for n in names]),
        ("content recognition, neutral captions (%)", [neutral_of(scores[n])["content"] for n in names]),
        ("R@3, style-prompted captions (%)", [scores[n]["style_prompted"]["r3"] for n in names]),
    )
    for ax, (label, values) in zip(axes, panels):
        ax.bar(names, [100 * (v or 0.0) for v in values], color=colours)
        ax.set_title(label, fontsize=10)
        ax.set_ylim(0, 100)
        for i, v in enumerate(values):
            ax.text(i, 100 * (v or 0.0) + 1.5, "n/a" if v is None else f"{100 * v:.0f}", ha="center", fontsize=9)
        ax.tick_params(axis="x", labelrotation=20)
    fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    first = out / "recognition.png"
    fig.savefig(first, dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(6, 3.8))
    values = [scores[n]["style_prompted"]["fmd"] for n in names]
    ax.bar(names, [v or 0.0 for v in values], color=colours)
    for i, v in enumerate(values):
        ax.text(i, v or 0.0, "n/a" if v is None else f"{v:.2f}", ha="center", va="bottom", fontsize=9)
    ax.set_title("FMD to real held-out clips, style-prompted captions (lower is better)", fontsize=10)
    ax.tick_params(axis="x", labelrotation=20)
    fig.tight_layout()
    second = out / "fmd.png"
    fig.savefig(second, dpi=110)
    plt.close(fig)
    return [first, second]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("protocol", choices=("synthetic", "bandai2"))
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument(
        "--methods",
        default="stats,onthefly",
        help="comma-separated: stats, onthefly, erd, umsd; METHOD-LABEL adds another B of METHOD (own --params)",
    )
    parser.add_argument(
        "--controls",
        default="",
        help="comma-separated methods whose output steps get a control B (their sources through the same steps, "
        "no network; needs the method's run)",
    )
    parser.add_argument("--missing", default=None, help="styles A lacks (default: synthetic 4, bandai2 all 6)")
    parser.add_argument("--fold", default=None, help="the leave-style-out rule: A lacks this LSO fold's styles")
    parser.add_argument("--clips", type=int, default=800, help="synthetic corpora size")
    parser.add_argument("--expand", type=int, default=100, help="neutral train clips of A to stylize (0 = all)")
    parser.add_argument("--size", default="small", choices=("tiny", "small"), help="pre-training preset")
    parser.add_argument("--prior-steps", type=int, default=1500)
    parser.add_argument("--encoder-steps", type=int, default=400)
    parser.add_argument("--classifier-epochs", type=int, default=2, help="A/B/C's own (unused) evaluators")
    parser.add_argument("--judge-prior-steps", type=int, default=100)
    parser.add_argument("--judge-encoder-steps", type=int, default=800)
    parser.add_argument("--judge-classifier-epochs", type=int, default=8)
    parser.add_argument("--guidance", type=float, default=3.0)
    parser.add_argument("--ddim", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0, help="sampling seed")
    parser.add_argument("--samples", type=int, default=1, help="samples per held-out caption (scores/NAME-xK.json)")
    parser.add_argument(
        "--neutral-samples", type=int, default=0, help="also score the neutral captions K times (the content target)"
    )
    parser.add_argument(
        "--prior-seeds", default="0", help="comma-separated: A, B and C are each pre-trained once per seed; means"
    )
    parser.add_argument(
        "--added-share",
        type=float,
        default=None,
        help="B's and C's priors draw this share of their clips from the added ones (A has none); default: uniform",
    )
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--method-base", choices=("own", "A"), default="own", help="the methods' base models")
    parser.add_argument("--params", default="{}", help='JSON: per-method params, e.g. {"onthefly": {"epochs": 1}}')
    parser.add_argument(
        "--extra-example",
        default="",
        help="comma-separated LABEL:CONTENT: method LABEL's styles each also learn from their first take of CONTENT "
        "in C's half, every example naming its content's plain A clip as its reference (the shipped configs' advice)",
    )
    parser.add_argument("--plots", type=Path, default=None, help="write PNG plots here")
    args = parser.parse_args()
    args.prior_seeds = [int(s) for s in args.prior_seeds.split(",")]
    work = args.work.resolve()
    work.mkdir(parents=True, exist_ok=True)
    methods = [m for m in args.methods.split(",") if m]
    corpus, judge_corpus = make_corpora(args, work)
    neutral = "neutral" if args.protocol == "synthetic" else "normal"
    if not (work / "split" / SPLIT_JSON).is_file():
        n_expand = args.expand or None
        words = style_words(args)
        missing = missing_styles(args)
        halves = bool(args.fold) and args.protocol == "bandai2"  # synthetic: the judge has a corpus of its own
        split_fn = lambda: split_by_style(  # noqa: E731
            corpus, work / "split", missing, neutral, n_expand, words=words, halves=halves
        )
        timed(work, "split", split_fn)
    split = StyleSplit.read(work / "split")
    if split.judge_ids:  # the judge learns the missing styles from the half C never adds
        judge_corpus = work / "corpora" / "judge"
        if not (judge_corpus / "Mean.npy").is_file():
            merge = lambda: merge_clips(work / "split" / BASE_DIR, judge_clips(work / "split"), judge_corpus)  # noqa: E731
            timed(work, "corpus_judge", merge)
    log(f"A lacks {split.missing}; base splits {split.base_splits}; held out {split.held_out}")
    pretrain(args, work, "judge", judge_corpus, judge_config(args))
    judge = Judge(work / "priors" / "judge")
    config = prior_config(args)
    # the methods read seed 0's A (--method-base A); the other seeds only re-train the priors that are compared
    by_seed = {"A": train_and_score(args, work, "A", work / "split" / BASE_DIR, judge, split)}
    if args.method_base == "own" and "onthefly" in {method_of(m) for m in methods}:
        pretrain(args, work, "A_method", work / "split" / BASE_DIR, method_base_config(args))
    for method in methods:  # each training set is scored as soon as its prior exists: a stopped run keeps figures
        by_seed[f"B_{method}"] = train_and_score(
            args, work, f"B_{method}", expand(args, work, split, method), judge, split
        )
    controls = [m for m in args.controls.split(",") if m]
    for method in controls:
        by_seed[f"B_{method}_control"] = train_and_score(
            args, work, f"B_{method}_control", control(work, method), judge, split
        )
    methods += [f"{m}_control" for m in controls]
    by_seed["C"] = train_and_score(args, work, "C", upper_bound(work), judge, split)
    scores = {name: runs["mean"] for name, runs in by_seed.items()}
    results = {
        "protocol": args.protocol,
        "fold": args.fold,
        "judge_takes_set_aside": len(split.judge_ids),
        "missing": split.missing,
        "present": split.present,
        "base_splits": split.base_splits,
        "held_out": split.held_out,
        "expand_clips": len(split.expand_ids),
        "settings": {k: str(v) for k, v in vars(args).items()},
        "prior_config": config.model_dump(),
        "prior_seeds": args.prior_seeds,
        "scores": scores,
        "scores_by_seed": {name: runs["seeds"] for name, runs in by_seed.items()},
        "spread_over_seeds": spread(by_seed),
        "added_clips_judged": {n: added_recognition(work, judge, n) for n in [*(f"B_{m}" for m in methods), "C"]},
        "summary": summarise(scores, methods, by_seed),
        "timings": json.loads((work / "timings.json").read_text()),
        "load": os.getloadavg(),
    }
    (work / "results.json").write_text(json.dumps(results, indent=1))
    print(table(scores))
    print(json.dumps(results["added_clips_judged"], indent=1))
    print(json.dumps(results["spread_over_seeds"], indent=1))
    print(json.dumps(results["summary"], indent=1))
    if args.plots:
        for path in plot(scores, args.plots, f"{args.protocol}: A lacks {', '.join(split.missing)}"):
            log(f"wrote {path}")


if __name__ == "__main__":
    main()
