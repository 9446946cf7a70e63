"""Output shards and completion markers: written atomically, verified by checksum, read back as rows.

A unit of work is done when its marker exists and the checksum in it matches the file it names; a
shard without a marker (a crash between rename and marker) is simply redone, overwriting the same name.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.io import atomic_path, fsync_dir, fsync_tree
from motionaug.augment.outputs.checksums import sha256_file
from motionaug.schemas.captions import Caption
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.shards import output_id, shard_schema


@dataclass
class TransferOutput:
    """One stylized clip. ``motion`` is (T, D) float32 un-normalised features like the input's."""

    source_id: str
    style: str
    motion: np.ndarray
    captions: list[Caption]
    scores: dict[str, float] = field(default_factory=dict)


WRITE_OPTIONS = {"compression": "zstd"}
TMP_SUFFIX = ".tmp"


def _captions(captions: Sequence[Caption]) -> list[dict]:
    return [{"text": c.text, "tokens": list(c.tokens), "start": c.start, "end": c.end} for c in captions]


def output_row(
    out: TransferOutput, source_captions: Sequence[Caption], context: dict, content: str | None, split: str | None
) -> dict:
    """One shard row; ``context`` carries run_id, method, fps, seed and artifact_ref."""
    motion = np.ascontiguousarray(out.motion, dtype=np.float32)
    return {
        "run_id": context["run_id"],
        "source_id": out.source_id,
        "output_id": output_id(out.source_id, out.style),
        "style": out.style,
        "method": context["method"],
        "motion": motion.reshape(-1),
        "n_frames": motion.shape[0],
        "n_feats": motion.shape[1],
        "fps": context["fps"],
        "original_captions": _captions(source_captions),
        "captions": _captions(out.captions),
        "content": content,
        "split": split,
        "seed": context["seed"],
        "artifact_ref": context["artifact_ref"],
        "scores": sorted((k, float(v)) for k, v in out.scores.items()),
    }


def rows_to_table(rows: Sequence[dict]) -> pa.Table:
    schema = shard_schema()
    columns = {f.name: [row[f.name] for row in rows] for f in schema}
    columns["motion"] = pa.array(columns["motion"], type=pa.list_(pa.float32()))
    return pa.Table.from_pydict(columns, schema=schema)


def write_shard(rows: Sequence[dict], path: Path) -> str:
    """Write rows to ``path`` via a temporary file renamed into place (fsynced); returns the file's sha256."""
    with atomic_path(path, fsync=True) as tmp:
        pq.write_table(rows_to_table(rows), tmp, **WRITE_OPTIONS)
    return sha256_file(path)


def publish_dir(tmp_dir: Path, final: Path) -> None:
    """Move a finished folder into place, replacing an unverified leftover of an earlier attempt; its files and
    the rename are flushed to disk first and after (a marker written next never outlives the folder)."""
    fsync_tree(tmp_dir)
    if final.exists():
        shutil.rmtree(final)
    os.replace(tmp_dir, final)
    fsync_dir(final.parent)


def iter_shard_rows(
    run_dir: Path, columns: list[str] | None = None, batch_size: int = 64, files: Sequence[Path] | None = None
) -> Iterator[dict]:
    """Rows of ``files`` (default: every shard file present) as Python dicts, one record batch in memory at a time.

    Readers that must not use a damaged shard pass ``files=verified_shards(...)`` (``augment.outputs.verify``).
    """
    found = sorted((Path(run_dir) / "shards").glob("style=*/unit-*.parquet")) if files is None else files
    for file in found:
        parquet = pq.ParquetFile(file)
        if parquet.schema_arrow.remove_metadata() != shard_schema().remove_metadata():
            raise MotionDataError(str(file), "not a motionaug shard (schema differs)")
        for batch in parquet.iter_batches(batch_size=batch_size, columns=columns):
            yield from batch.to_pylist()


def row_motion(row: dict) -> np.ndarray:
    return np.asarray(row["motion"], dtype=np.float32).reshape(row["n_frames"], row["n_feats"])


def row_captions(row: dict, key: str = "captions") -> list[Caption]:
    return [Caption(**c) for c in row[key]]


def row_clip(row: dict, source: str, meta: dict) -> MotionClip:
    """A stylized row as a train clip of a corpus (export, expansion)."""
    return MotionClip(
        row["output_id"],
        row_motion(row),
        row_captions(row),
        fps=float(np.float32(row["fps"])),
        content=row["content"],
        style=row["style"],
        source=source,
        meta={"split": "train", "source_id": row["source_id"], "method": row["method"]} | meta,
    )
