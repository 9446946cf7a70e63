"""Corpus formats behind one door: a HumanML3D folder or a Parquet corpus, detected from the path."""

from __future__ import annotations

import os
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Literal, Protocol

import pyarrow.compute as pc
import pyarrow.parquet as pq

from augment.clip import MotionClip
from augment.corpus.humanml3d import MOTION_DIR, HumanML3DReader, write_humanml3d
from augment.corpus.parquet import (
    ParquetCorpusWriter,
    check_corpus_schema,
    clips_to_table,
    parquet_files,
    read_parquet_corpus,
    table_to_clips,
)
from augment.corpus.rejects import Reject, read_rejects, write_rejects
from schemas.errors import MotionDataError
from schemas.corpus import CorpusInfo

__all__ = [
    "CorpusReader", "HumanML3DReader", "ParquetCorpusReader", "ParquetCorpusWriter", "Reject", "clips_to_table",
    "detect_format", "inspect_corpus", "open_corpus", "read_parquet_corpus", "read_rejects", "table_to_clips",
    "write_humanml3d", "write_rejects",
]  # fmt: skip

CorpusFormat = Literal["humanml3d", "parquet"]
SPLIT_NAMES = ("train", "val", "test", "train_val", "all")


class CorpusReader(Protocol):
    """What ``open_corpus`` returns: iterate for clips; ``rejects`` lists what the last pass skipped."""

    rejects: list[Reject]

    def __iter__(self) -> Iterator[MotionClip]: ...


class ParquetCorpusReader:
    """A Parquet corpus as a re-iterable source; it never skips rows, so ``rejects`` stays empty."""

    def __init__(self, path: str | os.PathLike[str], batch_size: int = 64) -> None:
        self.path = Path(path)
        self.batch_size = batch_size
        self.rejects: list[Reject] = []
        parquet_files(self.path)  # fail now, not at the first clip, when there is no corpus

    def __iter__(self) -> Iterator[MotionClip]:
        return read_parquet_corpus(self.path, self.batch_size)


def detect_format(path: str | os.PathLike[str]) -> CorpusFormat:
    """A folder with new_joint_vecs/ is HumanML3D; a .parquet file or a folder of them is Parquet."""
    path = Path(path)
    if path.is_dir() and (path / MOTION_DIR).is_dir():
        return "humanml3d"
    if (path.is_file() and path.suffix == ".parquet") or (path.is_dir() and any(path.glob("*.parquet"))):
        return "parquet"
    raise MotionDataError(str(path), f"not a corpus: expected a folder with {MOTION_DIR}/, a .parquet file or a folder of them")


def open_corpus(path: str | os.PathLike[str], **options: Any) -> CorpusReader:
    """Open either format; ``options`` go to the reader. HumanML3D reads all.txt, or every .npy without it."""
    if detect_format(path) == "parquet":
        return ParquetCorpusReader(path, **options)
    options.setdefault("split", "all" if (Path(path) / "all.txt").is_file() else None)
    return HumanML3DReader(path, **options)


REJECTS_FILE = "rejects.jsonl"


def inspect_corpus(path: str | os.PathLike[str], **options: Any) -> CorpusInfo:
    """Count clips, frames, hours, captions and labels in one streaming pass.

    ``rejects`` adds what the reader skips now to what an import recorded in ``rejects.jsonl``.
    """
    path = Path(path)
    info = _inspect_parquet(path) if detect_format(path) == "parquet" else _inspect_humanml3d(path, **options)
    recorded = (path if path.is_dir() else path.parent) / REJECTS_FILE
    if recorded.is_file():
        info.rejects += len(read_rejects(recorded))
    return info


def _inspect_humanml3d(path: Path, **options: Any) -> CorpusInfo:
    reader = open_corpus(path, **options)
    info = CorpusInfo(format="humanml3d", path=str(path), splits=_count_split_files(Path(path)))
    contents: Counter[str] = Counter()
    styles: Counter[str] = Counter()
    seconds = 0.0
    for clip in reader:
        info.clips += 1
        info.frames += clip.n_frames
        info.captions += len(clip.captions)
        seconds += clip.n_frames / clip.fps
        contents.update([clip.content] if clip.content else [])
        styles.update([clip.style] if clip.style else [])
    info.hours, info.rejects = seconds / 3600, len(reader.rejects)
    info.contents, info.styles = dict(sorted(contents.items())), dict(sorted(styles.items()))
    return info


def _count_split_files(root: Path) -> dict[str, int]:
    counts = {}
    for name in SPLIT_NAMES:
        split_file = root / f"{name}.txt"
        if split_file.is_file():
            with open(split_file, encoding="utf-8") as handle:
                counts[name] = sum(1 for line in handle if line.strip())
    return counts


def _inspect_parquet(path: Path) -> CorpusInfo:
    """Reads only the small columns: the motion column is never decoded."""
    info = CorpusInfo(format="parquet", path=str(path))
    counters = {"content": Counter(), "style": Counter(), "split": Counter()}
    seconds = 0.0
    for file in parquet_files(path):
        parquet = pq.ParquetFile(file)
        meta = check_corpus_schema(parquet.schema_arrow, str(file))
        info.schema_version, info.skeleton = int(meta["schema_version"]), meta["skeleton"] or None
        info.feature_dim = int(meta["feature_dim"]) if meta["feature_dim"] else None
        for batch in parquet.iter_batches(columns=["n_frames", "fps", "captions", *counters]):
            n_frames = batch.column("n_frames").to_numpy()
            info.clips += batch.num_rows
            info.frames += int(n_frames.sum())
            info.captions += int(pc.sum(pc.list_value_length(batch.column("captions"))).as_py() or 0)
            seconds += float((n_frames / batch.column("fps").to_numpy()).sum())
            for name, counter in counters.items():
                counter.update(value for value in batch.column(name).to_pylist() if value is not None)
    info.hours = seconds / 3600
    info.contents, info.styles, info.splits = (dict(sorted(counters[k].items())) for k in ("content", "style", "split"))
    return info
