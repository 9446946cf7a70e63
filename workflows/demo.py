"""``motionaug demo``: the embedded default end to end, resumable.

Renders the synthetic corpus (once), learns three styles from two example clips each (a walk and a wave, each
against a plain clip of its content) with the product's default method, stylizes every neutral clip, and exports
the expanded corpus in the HumanML3D layout. The default is Style-ERD with its output shapers (the winner of the
leave-style-out table, ``bench/RESULTS.md`` section 0). The network (Style-ERD's, or on-the-fly's prior) trains once
on a copy of the corpus without the demo styles (the product's style filter), so that each style is learnt from its
examples as a user's unseen style is, never from the corpus's labelled clips of it. Each step leaves a completion
marker, so running the demo again finishes at once.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from motionaug.augment.corpus.humanml3d import read_labels
from motionaug.augment.corpus.style_sets import write_without_styles
from motionaug.augment.io import atomic_write_text
from motionaug.augment.methods.shapers import STYLE_ERD_CHAIN
from motionaug.augment.outputs.export import ExportSummary, export_run
from motionaug.augment.render.viewer import ViewerSummary, write_run_viewer
from motionaug.augment.synth import STYLE_WORDS, generate_corpus
from motionaug.augment.text.tokens import parse_caption_line
from motionaug.augment.training.pretrain import PretrainConfig, fit_evaluators
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.run_config import RunConfig
from motionaug.schemas.styles import StyleExample, StyleSpec
from motionaug.workflows.executor import RunProgress
from motionaug.workflows.ray_executor import RunSummary, execute_run

DEMO_STYLES = ("proud", "depressed", "old")
EXAMPLE_CONTENTS = ("walk", "wave")  # each demo style's examples: one clip that travels and one in place
DEMO_SEED = 0
DONE = "_SUCCESS"
DEMO_METHODS = ("erd", "onthefly", "stats")
DEFAULT_METHOD = "erd"
# Per method and base-model size: the method's params and output shapers. `small` is the demo's share of the
# 10-minute budget on 2 cores: Style-ERD's network trains 1,500 steps (its shipped configs: 3,000, which takes the
# demo past 9 minutes) and keeps their output shapers; on-the-fly's prior and motion encoder stop earlier than
# `motionaug pretrain` would (``train``, overrides of the size's preset) and each fine-tune has a step budget.
# `tiny` is a smoke run of the same path (seconds of training, untrained-looking output).
ERD_SHAPERS = list(STYLE_ERD_CHAIN)  # as configs/erd-synthetic.yaml chains them
DEMO_PROFILES: dict[str, dict[str, dict[str, Any]]] = {
    "erd": {
        "small": {"params": {"neutral_style": "neutral", "train": {"steps": 1500}}, "shapers": ERD_SHAPERS},
        "tiny": {
            "params": {
                "neutral_style": "neutral",
                "train": {"steps": 3, "batch_size": 4, "window_s": 0.8},
                "branch": {"steps": 3, "batch_size": 4},
            },
            "shapers": ERD_SHAPERS,
        },
    },
    "onthefly": {
        "small": {"params": {"max_steps": 40, "train": {"prior_steps": 1400, "encoder_steps": 400}}},
        "tiny": {"params": {"max_steps": 2, "pair_steps": 10, "batch_size": 4}},
    },
    "stats": {"small": {}, "tiny": {}},
}
DEMO_SIZES = ("small", "tiny")


@dataclass
class DemoResult:
    corpus: Path
    run: RunSummary
    export: ExportSummary
    viewer: ViewerSummary


def once(root: Path, build: Callable[[Path], Any]) -> Path:
    """``root`` as ``build`` writes it, once: a folder without its completion marker (half-written) is rebuilt
    from scratch."""
    if (root / DONE).is_file():
        return root
    if root.exists():
        shutil.rmtree(root)
    build(root)
    atomic_write_text(root / DONE, "")
    return root


def ensure_corpus(root: Path, clips: int, seed: int = DEMO_SEED) -> Path:
    """The synthetic corpus at ``root``."""
    return once(root, lambda out: generate_corpus(out, clips, seed=seed))


def demo_styles(corpus: Path) -> list[StyleSpec]:
    """Per demo style, its first training clip of each ``EXAMPLE_CONTENTS`` (one that travels, one in place, as
    docs/methods.md advises), described by its own caption, with the first plain training clip of that content named
    as its reference."""
    labels = read_labels(corpus)

    def first(style: str, content: str) -> str:
        for cid, r in sorted(labels.items()):
            if r["style"] == style and r["content"] == content and r["meta"].get("split") == "train":
                return cid
        raise MotionDataError(str(corpus), f"no training {content} in style {style!r} to use as an example")

    specs = []
    for style in DEMO_STYLES:
        examples = []
        for content in EXAMPLE_CONTENTS:
            clip_id = first(style, content)
            first_line = (corpus / "texts" / f"{clip_id}.txt").read_text(encoding="utf-8").splitlines()[0]
            description = parse_caption_line(first_line, clip_id).text
            examples.append(StyleExample(source=clip_id, description=description, reference=first("neutral", content)))
        specs.append(StyleSpec(name=style, words=STYLE_WORDS[style], examples=examples))
    return specs


def ensure_training_corpus(corpus: Path, root: Path) -> Path:
    """The corpus without the demo styles and their counterparts at ``root``: what the demo's network trains on."""
    return once(root, lambda out: write_without_styles(corpus, out, DEMO_STYLES))


def ensure_evaluators(corpus: Path, root: Path, size: str) -> Path:
    """The demo's judges at ``root``: content and style classifiers fit on the whole corpus's train split, demo
    styles included, kept apart from the method's models (``motionaug evaluate`` scores the run with them)."""
    return once(root, lambda out: fit_evaluators(corpus, out, PretrainConfig.for_size(size, seed=DEMO_SEED)))


def method_folder(out: Path, name: str, method: str) -> Path:
    """``out/name`` for the default method, ``out/name-METHOD`` for another: switching methods starts a new run."""
    return out / (name if method == DEFAULT_METHOD else f"{name}-{method}")


def demo_config(
    corpus: Path,
    run_dir: Path,
    base_models: Path,
    method: str = DEFAULT_METHOD,
    size: str = "small",
    training_corpus: Path | None = None,
    evaluators: Path | None = None,
) -> RunConfig:
    """The demo run: every neutral clip of the corpus in every demo style; ``training_corpus``: what the method's
    once-per-run models train on (None: the corpus); ``evaluators``: the judges ``motionaug evaluate`` uses."""
    if method not in DEMO_METHODS:
        raise MotionDataError("demo --method", f"unknown method {method!r} (choose from {', '.join(DEMO_METHODS)})")
    if size not in DEMO_SIZES:
        raise MotionDataError("demo --size", f"unknown size {size!r} (choose from {', '.join(DEMO_SIZES)})")
    profile = DEMO_PROFILES[method][size]
    return RunConfig.model_validate(
        {
            "corpus": {"path": corpus, "filters": {"source_styles": ["neutral"], "min_frames": 40, "max_frames": 199}},
            "styles": [s.model_dump() for s in demo_styles(corpus)],
            "method": {"name": method, "params": profile.get("params", {}), "shapers": profile.get("shapers", [])},
            "base_models": {"path": base_models, "size": size, "corpus": training_corpus},
            # training and fine-tunes take both cores (one task at a time); transfers one core each, two at a time
            "compute": {"num_cpus": 2, "finetune_cpus": 2, "transfer_cpus": 1, "batch_size": 32, "unit_size": 128},
            "output": run_dir,
            "evaluators": evaluators,
            "seed": DEMO_SEED,
        }
    )


def run_demo(
    out: Path,
    clips: int = 1000,
    progress: RunProgress | None = None,
    base_models: Path | None = None,
    method: str = DEFAULT_METHOD,
    size: str = "small",
) -> DemoResult:
    """Corpus -> judges -> base models -> run -> HumanML3D export and the run's 3D viewer under ``out``; every step
    but the viewer (rewritten, seconds) skipped when already complete."""
    corpus = ensure_corpus(out / "corpus", clips)
    training = ensure_training_corpus(corpus, out / "corpus-without-demo-styles") if method != "stats" else None
    config = demo_config(
        corpus,
        method_folder(out, "run", method),
        base_models or method_folder(out, "base_models", method),
        method,
        size,
        training,
        ensure_evaluators(corpus, out / "evaluators", size),
    )
    summary = execute_run(config, progress=progress)
    exported = export_run(summary.run_dir, method_folder(out, "expanded", method))
    viewer = write_run_viewer(summary.run_dir)
    return DemoResult(corpus=corpus, run=summary, export=exported, viewer=viewer)
