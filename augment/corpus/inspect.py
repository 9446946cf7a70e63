"""Counting what a corpus holds (``motionaug corpus inspect``) in one streaming pass."""

from __future__ import annotations

import os
from collections import Counter
from pathlib import Path
from typing import Any

import pyarrow.compute as pc
import pyarrow.parquet as pq

from motionaug.augment.corpus.corpus import Corpus, detect_format
from motionaug.augment.corpus.parquet import check_corpus_schema, parquet_files
from motionaug.augment.corpus.rejects import read_rejects
from motionaug.schemas.corpus import CorpusInfo

SPLIT_NAMES = ("train", "val", "test", "train_val", "all")


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
    reader = Corpus(path, **options)
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
