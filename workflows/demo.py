"""``motionaug demo``: the embedded default end to end, resumable.

Renders the synthetic corpus (once), takes one example clip per demo style, runs the augmentation workflow
over every neutral clip, and exports the expanded corpus in the HumanML3D layout. Each step leaves a
completion marker, so running the demo again with the same folder finishes at once.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

from augment.corpus.humanml3d import read_labels
from augment.corpus.tokens import parse_caption_line
from augment.export import ExportSummary, export_run
from augment.io import atomic_write_text
from augment.synth import STYLE_WORDS, generate_corpus
from schemas.errors import MotionDataError
from schemas.run_config import RunConfig
from schemas.styles import StyleExample, StyleSpec
from workflows.ray_executor import RunProgress, RunSummary, execute_run

DEMO_STYLES = ("proud", "depressed", "old")
DEMO_SEED = 0
DONE = "_SUCCESS"


@dataclass
class DemoResult:
    corpus: Path
    run: RunSummary
    export: ExportSummary


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
            (cid for cid, r in sorted(labels.items()) if r["style"] == style and r["content"] == "walk"
             and r["meta"].get("split") == "train"),
            None,
        )  # fmt: skip
        if clip_id is None:
            raise MotionDataError(str(corpus), f"no training walk in style {style!r} to use as the example")
        first_line = (corpus / "texts" / f"{clip_id}.txt").read_text(encoding="utf-8").splitlines()[0]
        description = parse_caption_line(first_line, clip_id).text
        specs.append(StyleSpec(name=style, words=STYLE_WORDS[style], examples=[StyleExample(source=clip_id, description=description)]))
    return specs


def demo_config(corpus: Path, run_dir: Path, method: str = "stats") -> RunConfig:
    return RunConfig.model_validate({
        "corpus": {"path": corpus, "filters": {"source_styles": ["neutral"], "min_frames": 40, "max_frames": 199}},
        "styles": [s.model_dump() for s in demo_styles(corpus)],
        "method": {"name": method},
        "compute": {"num_cpus": 2, "batch_size": 32, "unit_size": 128},
        "output": run_dir,
        "seed": DEMO_SEED,
    })  # fmt: skip


def run_demo(out: Path, clips: int = 1000, progress: RunProgress | None = None) -> DemoResult:
    """Corpus -> run -> HumanML3D export under ``out``; every step skipped when already complete."""
    corpus = ensure_corpus(out / "corpus", clips)
    summary = execute_run(demo_config(corpus, out / "run"), progress=progress)
    exported = export_run(summary.run_dir, out / "expanded")
    return DemoResult(corpus=corpus, run=summary, export=exported)
