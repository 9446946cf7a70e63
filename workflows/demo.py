"""``motionaug demo``: the embedded default end to end, resumable.

Renders the synthetic corpus (once), pre-trains ``small`` base models on it (once; cached in the demo folder or
``--base-models``), learns three styles from one example clip each with the on-the-fly diffusion method, stylizes
every neutral clip, and exports the expanded corpus in the HumanML3D layout. Each step leaves a completion
marker, so running the demo again with the same folder finishes at once.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from motionaug.augment.corpus.humanml3d import read_labels
from motionaug.augment.io import atomic_write_text
from motionaug.augment.outputs.export import ExportSummary, export_run
from motionaug.augment.render.viewer import ViewerSummary, write_run_viewer
from motionaug.augment.synth import STYLE_WORDS, generate_corpus
from motionaug.augment.text.tokens import parse_caption_line
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.run_config import RunConfig
from motionaug.schemas.styles import StyleExample, StyleSpec
from motionaug.workflows.executor import RunProgress
from motionaug.workflows.ray_executor import RunSummary, execute_run

DEMO_STYLES = ("proud", "depressed", "old")
DEMO_SEED = 0
DONE = "_SUCCESS"
DEMO_METHODS = ("onthefly", "stats")
# Per base-model size: the on-the-fly method's params. `small` is the demo's share of the 10-minute budget on 2
# cores: the prior and the motion encoder stop earlier than `motionaug pretrain` would (``train``, overrides of the
# size's pre-training preset), and each style's fine-tune has a step budget, so the whole demo fits. `tiny` is a
# smoke run of the same path (seconds of training, untrained-looking output).
DEMO_PROFILES: dict[str, dict[str, Any]] = {
    "small": {"max_steps": 40, "train": {"prior_steps": 1400, "encoder_steps": 400}},
    "tiny": {"max_steps": 2, "pair_steps": 10, "batch_size": 4},
}


@dataclass
class DemoResult:
    corpus: Path
    run: RunSummary
    export: ExportSummary
    viewer: ViewerSummary


def ensure_corpus(root: Path, clips: int, seed: int = DEMO_SEED) -> Path:
    """The synthetic corpus at ``root``; a half-written one (no marker) is rendered again from scratch."""
    if (root / DONE).is_file():
        return root
    if root.exists():
        shutil.rmtree(root)
    generate_corpus(root, clips, seed=seed)
    atomic_write_text(root / DONE, "")
    return root


def demo_styles(corpus: Path) -> list[StyleSpec]:
    """One example per demo style: the first training walk in that style, described by its own caption."""
    labels = read_labels(corpus)
    specs = []
    for style in DEMO_STYLES:
        clip_id = next(
            (
                cid
                for cid, r in sorted(labels.items())
                if r["style"] == style and r["content"] == "walk" and r["meta"].get("split") == "train"
            ),
            None,
        )
        if clip_id is None:
            raise MotionDataError(str(corpus), f"no training walk in style {style!r} to use as the example")
        first_line = (corpus / "texts" / f"{clip_id}.txt").read_text(encoding="utf-8").splitlines()[0]
        description = parse_caption_line(first_line, clip_id).text
        specs.append(
            StyleSpec(
                name=style, words=STYLE_WORDS[style], examples=[StyleExample(source=clip_id, description=description)]
            )
        )
    return specs


def demo_config(
    corpus: Path, run_dir: Path, base_models: Path, method: str = "onthefly", size: str = "small"
) -> RunConfig:
    """The demo run: every neutral clip of the corpus in every demo style."""
    if method not in DEMO_METHODS:
        raise MotionDataError("demo --method", f"unknown method {method!r} (choose from {', '.join(DEMO_METHODS)})")
    if size not in DEMO_PROFILES:
        raise MotionDataError("demo --size", f"unknown size {size!r} (choose from {', '.join(DEMO_PROFILES)})")
    params = DEMO_PROFILES[size]
    return RunConfig.model_validate(
        {
            "corpus": {"path": corpus, "filters": {"source_styles": ["neutral"], "min_frames": 40, "max_frames": 199}},
            "styles": [s.model_dump() for s in demo_styles(corpus)],
            "method": {"name": method, "params": params if method == "onthefly" else {}},
            "base_models": {"path": base_models, "size": size},
            # pre-training and fine-tunes take both cores (one task at a time); transfers one core each, two at a time
            "compute": {"num_cpus": 2, "finetune_cpus": 2, "transfer_cpus": 1, "batch_size": 32, "unit_size": 128},
            "output": run_dir,
            "seed": DEMO_SEED,
        }
    )


def run_demo(
    out: Path,
    clips: int = 1000,
    progress: RunProgress | None = None,
    base_models: Path | None = None,
    method: str = "onthefly",
    size: str = "small",
) -> DemoResult:
    """Corpus -> base models -> run -> HumanML3D export and the run's 3D viewer under ``out``; every step but the
    viewer (rewritten, seconds) skipped when already complete."""
    corpus = ensure_corpus(out / "corpus", clips)
    config = demo_config(corpus, out / "run", base_models or out / "base_models", method, size)
    summary = execute_run(config, progress=progress)
    exported = export_run(summary.run_dir, out / "expanded")
    viewer = write_run_viewer(summary.run_dir)
    return DemoResult(corpus=corpus, run=summary, export=exported, viewer=viewer)
