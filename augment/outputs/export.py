"""A finished run as a training set: the original corpus plus its stylized clips, in one of two layouts.

``humanml3d``: the folder MDM's ``Text2MotionDatasetV2`` reads (``new_joint_vecs/``, revised captions with lemma/POS
tokens in ``texts/``, split files). Stylized copies of train clips go to the train split files only; copies of
val/test clips are left out, since they would leak test content into training. Mean/Std are recomputed from the
exported train split or kept from the source. ``parquet``: one merged dataset in the corpus Arrow schema
(``schemas/corpus.py``). Both are written into a temporary folder renamed into place, so an export is all or
nothing; exporting again replaces an earlier export (known by its ``export.json``) and gives the same bytes.
"""

from __future__ import annotations

import json
import shutil
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from motionaug.augment.corpus import Corpus, HumanML3DReader, ParquetCorpusWriter, write_humanml3d
from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.corpus.humanml3d import ADDED_SPLIT
from motionaug.augment.io import atomic_write_text
from motionaug.augment.motion.features import Normalizer, compute_mean_std
from motionaug.augment.outputs.run_dir import RunDir
from motionaug.augment.outputs.shards import iter_shard_rows, row_clip
from motionaug.augment.outputs.verify import verified_shards
from motionaug.schemas.errors import MotionDataError

EXPORT_FILE = "export.json"
ExportFormat = Literal["humanml3d", "parquet"]


@dataclass
class ExportSummary:
    out: Path
    format: str
    originals: int = 0
    stylized: int = 0
    held_out: int = 0
    below_score: int = 0
    splits: dict[str, int] = field(default_factory=dict)


class _Collector:
    """Streams originals then stylized clips, recording which split each id belongs to as it goes."""

    def __init__(
        self,
        run_dir: Path,
        run_id: str,
        corpus: Path,
        min_score: float | None,
        score_name: str,
        summary: ExportSummary,
        shards: list[Path],
        evaluated: dict[str, float] | None = None,
    ) -> None:
        self.run_dir, self.run_id, self.corpus, self.shards = run_dir, run_id, corpus, shards
        self.min_score, self.score_name = min_score, score_name
        self.evaluated = evaluated  # output_id -> content score from scores.parquet (``motionaug evaluate``)
        self.summary = summary
        self.splits: dict[str, list[str]] = {"train": [], "val": [], "test": [], ADDED_SPLIT: []}
        self.progress: Callable[[str, int, int, dict[str, float]], None] | None = None
        self.rows = 0  # stylized rows the run holds (the manifest's count)

    def clips(self) -> Iterator[MotionClip]:
        yield from self._originals()
        yield from self._stylized()

    def _originals(self) -> Iterator[MotionClip]:
        corpus = Corpus(self.corpus)
        split_of = corpus.file_splits()
        for clip in corpus:
            split = Corpus.split_of(clip, split_of)
            if split in self.splits:
                self.splits[split].append(clip.id)
            clip.meta = {k: v for k, v in clip.meta.items() if k != "split"} | ({"split": split} if split else {})
            self.summary.originals += 1
            if self.progress is not None:
                self.progress("originals", self.summary.originals, 0, {})
            yield clip

    def _stylized(self) -> Iterator[MotionClip]:
        for seen, row in enumerate(iter_shard_rows(self.run_dir, files=self.shards), 1):
            if self.progress is not None:
                self.progress("stylized", seen, max(self.rows, seen), {})
            if row["split"] != "train":
                self.summary.held_out += 1
                continue
            if self.min_score is not None and self._score(row) < self.min_score:
                self.summary.below_score += 1
                continue
            self.splits["train"].append(row["output_id"])
            self.splits[ADDED_SPLIT].append(row["output_id"])
            self.summary.stylized += 1
            yield row_clip(row, f"motionaug:{self.run_id}", {"run_id": self.run_id})

    def _score(self, row: dict) -> float:
        if self.evaluated is not None:
            return self.evaluated.get(row["output_id"], -np.inf)
        return _shard_score(dict(row["scores"] or []), self.score_name)


def _shard_score(scores: dict[str, float], name: str) -> float:
    """A method's score by name; ``content`` also finds ``content_score`` (the diffusion method's name)."""
    return scores.get(name, scores.get(f"{name}_score", -np.inf))


def _check_scores(
    run_dir: Path, shards: list[Path], min_score: float | None, score_name: str, evaluated: dict[str, float] | None
) -> None:
    if min_score is None:
        return
    if evaluated is not None:
        if evaluated:
            return
        raise MotionDataError(
            str(run_dir / "scores.parquet"), "--min-content-score given, but no clip has a content score"
        )
    for row in iter_shard_rows(run_dir, columns=["scores"], files=shards):
        if np.isfinite(_shard_score(dict(row["scores"] or []), score_name)):
            return
    reason = f"--min-content-score given, but no row has a {score_name!r} score (method too simple?)"
    raise MotionDataError(str(run_dir), reason)


def export_run(
    run_dir: str | Path,
    out: str | Path,
    fmt: ExportFormat = "humanml3d",
    min_content_score: float | None = None,
    keep_mean_std: bool = False,
    score_name: str = "content",
    progress: Callable[[str, int, int, dict[str, float]], None] | None = None,
    allow_empty: bool = False,
) -> ExportSummary:
    """Write the original corpus + the run's stylized train clips to ``out``; returns what went where.

    ``progress(stage, done, total, {})`` hears of each clip read (``originals``: total 0, unknown; ``stylized``).
    An export that would add no stylized clip is an error (nothing is written) unless ``allow_empty``.
    """
    run_dir, out = Path(run_dir), Path(out)
    if fmt not in ("humanml3d", "parquet"):
        raise MotionDataError("--format", f"unknown export format {fmt!r}; use humanml3d or parquet")
    manifest = RunDir(run_dir).manifest()
    run_id, config = manifest.run_id, manifest.config
    corpus = Path(config["corpus"]["path"])
    if not corpus.exists():
        raise MotionDataError(str(corpus), "the run's source corpus is gone; exports need it for the original clips")
    _check_target(out)
    shards = verified_shards(RunDir(run_dir))
    evaluated = RunDir(run_dir).content_scores() if min_content_score is not None else None
    _check_scores(run_dir, shards, min_content_score, score_name, evaluated)
    summary = ExportSummary(out=out, format=fmt)
    collector = _Collector(run_dir, run_id, corpus, min_content_score, score_name, summary, shards, evaluated)
    collector.progress, collector.rows = progress, manifest.rows
    tmp = out.with_name(f".{out.name}.{uuid.uuid4().hex[:12]}.tmp")
    try:
        if fmt == "humanml3d":
            _write_humanml3d(collector, tmp, corpus, keep_mean_std)
        else:
            with ParquetCorpusWriter(tmp, rows_per_file=10_000) as writer:
                writer.write_all(collector.clips())
        summary.splits = {k: len(v) for k, v in collector.splits.items()}
        record = {
            "run_id": run_id,
            "format": fmt,
            "originals": summary.originals,
            "stylized": summary.stylized,
            "held_out": summary.held_out,
            "below_score": summary.below_score,
            "splits": summary.splits,
            "min_content_score": min_content_score,
        }
        if summary.stylized == 0 and not allow_empty:
            raise empty_export(out, manifest.rows, summary)
        atomic_write_text(tmp / EXPORT_FILE, json.dumps(record, indent=1, sort_keys=True) + "\n")
        _publish(tmp, out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return summary


def empty_export(out: Path, rows: int, summary: ExportSummary) -> MotionDataError:
    """Why an export adds no stylized clip: the run has none, or every one is a val/test copy or below the score."""
    if rows == 0:
        why = "the run has 0 stylized rows"
    else:
        why = f"of the run's {rows} stylized rows, {summary.held_out} are val/test copies (left out)"
        why += f" and {summary.below_score} are below --min-content-score" if summary.below_score else ""
    return MotionDataError(str(out), f"export would add 0 stylized clips: {why}; pass --allow-empty to export anyway")


def _write_humanml3d(collector: _Collector, tmp: Path, corpus: Path, keep_mean_std: bool) -> None:
    # the split lists are filled while write_humanml3d consumes the clips; it writes split files at the end
    splits = collector.splits
    train_val: list[str] = []
    write_humanml3d(collector.clips(), tmp, splits={**splits, "train_val": train_val})
    train_val.extend(splits["train"] + splits["val"])
    _write_split(tmp, "train_val", train_val)
    if keep_mean_std and Corpus(corpus).format == "humanml3d":
        mean, std = HumanML3DReader(corpus).mean_std()
        Normalizer(mean, std).save(tmp)
        return
    train = HumanML3DReader(tmp, split="train", split_spans=False, on_error="raise")
    compute_mean_std(clip.motion for clip in train).save(tmp)


def _write_split(root: Path, name: str, ids: list[str]) -> None:
    atomic_write_text(root / f"{name}.txt", "".join(f"{i}\n" for i in ids))


def _check_target(out: Path) -> None:
    if out.exists() and any(out.iterdir()) and not (out / EXPORT_FILE).is_file():
        raise MotionDataError(str(out), "folder is not empty and holds no earlier export; choose another --out")


def _publish(tmp: Path, out: Path) -> None:
    """Swap the finished folder in; an earlier export moves aside first and is deleted after."""
    old = out.with_name(f".{out.name}.{uuid.uuid4().hex[:12]}.old.tmp")
    if out.exists():
        out.rename(old)
    tmp.rename(out)
    shutil.rmtree(old, ignore_errors=True)
