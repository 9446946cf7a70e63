"""The Parquet corpus: one row per clip in plain Arrow columns (see ``schemas.corpus``), streamed.

Writing buffers one row group at a time and publishes each file by renaming it into place when it is
complete; reading goes batch by batch, so memory is bounded by the row group, never the corpus.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from pathlib import Path
from types import TracebackType

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.corpus.humanml3d import check_motion
from motionaug.augment.io import temp_path_for
from motionaug.schemas.captions import Caption
from motionaug.schemas.corpus import (
    CAPTION_TYPE,
    CORPUS_FIELDS,
    CORPUS_SCHEMA_VERSION,
    META_FEATURE_DIM,
    META_SCHEMA_VERSION,
    META_SKELETON,
    corpus_schema,
)
from motionaug.schemas.errors import MotionDataError

PART_PATTERN = "part-*.parquet"
# Motion floats do not repeat, so no dictionary; byte-stream-split lets zstd find the shared exponent
# bytes (smaller and faster to read on real features). Repetitive labels keep a dictionary.
WRITE_OPTIONS = {
    "compression": "zstd",
    "column_encoding": {"motion.list.element": "BYTE_STREAM_SPLIT"},
    "use_dictionary": [
        "captions.list.element.tokens.list.element",
        "content",
        "style",
        "source",
        "split",
        "meta.key_value.key",
        "meta.key_value.value",
    ],
}


def clips_to_table(clips: Iterable[MotionClip], skeleton: str = "t2m", feature_dim: int = 263) -> pa.Table:
    """Clips as one Arrow table of the corpus schema; motion flattened row-major."""
    clips = list(clips)
    for clip in clips:
        check_motion(clip.motion, feature_dim, f"clip {clip.id!r}")
    flats = [np.ascontiguousarray(clip.motion, dtype=np.float32).reshape(-1) for clip in clips]
    offsets = np.concatenate([[0], np.cumsum([flat.size for flat in flats])]).astype(np.int32)
    values = np.concatenate(flats) if flats else np.zeros(0, np.float32)
    columns = {
        "id": pa.array([clip.id for clip in clips], pa.string()),
        "motion": pa.ListArray.from_arrays(pa.array(offsets), pa.array(values)),
        "n_frames": pa.array([clip.motion.shape[0] for clip in clips], pa.int32()),
        "n_feats": pa.array([clip.motion.shape[1] for clip in clips], pa.int32()),
        "fps": pa.array([clip.fps for clip in clips], pa.float32()),
        "captions": pa.array([[c.model_dump() for c in clip.captions] for clip in clips], pa.list_(CAPTION_TYPE)),
        "content": pa.array([clip.content for clip in clips], pa.string()),
        "style": pa.array([clip.style for clip in clips], pa.string()),
        "source": pa.array([clip.source for clip in clips], pa.string()),
        "split": pa.array([clip.meta.get("split") for clip in clips], pa.string()),
        "meta": pa.array(
            [[(k, v) for k, v in sorted(clip.meta.items()) if k != "split"] for clip in clips],
            pa.map_(pa.string(), pa.string()),
        ),
    }
    schema = corpus_schema(skeleton, feature_dim)
    return pa.Table.from_arrays([columns[field.name] for field in schema], schema=schema)


def _f32(value: float) -> float:
    """The shortest decimal that a float32 holds, so 0.1 stored as float32 reads back as 0.1."""
    return float(str(np.float32(value)))


def table_to_clips(table: pa.Table, source: str = "table") -> list[MotionClip]:
    """Rows of a corpus table back to clips; a row whose motion size disagrees with its shape is an error."""
    motion = table.column("motion").combine_chunks()
    offsets = motion.offsets.to_numpy()
    values = motion.values.to_numpy(zero_copy_only=False)
    shapes = zip(table.column("n_frames").to_pylist(), table.column("n_feats").to_pylist())
    rows = table.drop_columns(["motion"]).to_pylist()
    clips = []
    for i, (row, (n_frames, n_feats)) in enumerate(zip(rows, shapes)):
        start, stop = int(offsets[i]), int(offsets[i + 1])
        if stop - start != n_frames * n_feats:
            raise MotionDataError(
                f"{source} row {i} ({row['id']})",
                f"motion has {stop - start} values, n_frames*n_feats is {n_frames * n_feats}",
            )
        clips.append(_row_to_clip(row, values[start:stop].reshape(n_frames, n_feats).copy()))
    return clips


def _row_to_clip(row: dict, motion: np.ndarray) -> MotionClip:
    captions = [
        Caption(text=c["text"], tokens=c["tokens"], start=_f32(c["start"]), end=_f32(c["end"])) for c in row["captions"]
    ]
    meta = dict(row["meta"] or [])
    if row["split"] is not None:
        meta["split"] = row["split"]
    return MotionClip(
        row["id"],
        motion,
        captions,
        fps=_f32(row["fps"]),
        content=row["content"],
        style=row["style"],
        source=row["source"],
        meta=meta,
    )


def parquet_files(path: str | os.PathLike[str]) -> list[Path]:
    """The corpus files: the path itself, or the sorted ``*.parquet`` files of a folder."""
    path = Path(path)
    files = [path] if path.is_file() else sorted(path.glob("*.parquet")) if path.is_dir() else []
    if not files:
        raise MotionDataError(str(path), "no Parquet corpus here (no .parquet file)")
    return files


def check_corpus_schema(schema: pa.Schema, source: str) -> dict[str, str]:
    """The corpus metadata of a file, or an error if it is not a corpus this version reads."""
    metadata = schema.metadata or {}
    if META_SCHEMA_VERSION not in metadata:
        raise MotionDataError(source, f"not a motionaug corpus: no {META_SCHEMA_VERSION.decode()} in the schema")
    version = int(metadata[META_SCHEMA_VERSION])
    if version > CORPUS_SCHEMA_VERSION:
        raise MotionDataError(
            source, f"corpus schema version {version} is newer than this reader ({CORPUS_SCHEMA_VERSION})"
        )
    missing = [field.name for field in CORPUS_FIELDS if field.name not in schema.names]
    if missing:
        raise MotionDataError(source, f"corpus columns missing: {missing}")
    return {
        "schema_version": str(version),
        "skeleton": metadata.get(META_SKELETON, b"").decode(),
        "feature_dim": metadata.get(META_FEATURE_DIM, b"").decode(),
    }


def read_parquet_corpus(path: str | os.PathLike[str], batch_size: int = 64) -> Iterator[MotionClip]:
    """Stream the clips of a corpus file or folder, ``batch_size`` rows in memory at a time."""
    for file in parquet_files(path):
        parquet = pq.ParquetFile(file)
        check_corpus_schema(parquet.schema_arrow, str(file))
        for batch in parquet.iter_batches(batch_size=batch_size):
            yield from table_to_clips(pa.Table.from_batches([batch]), source=str(file))


class ParquetCorpusWriter:
    """Write clips to ``<name>.parquet`` or, for a folder, ``part-00000.parquet``, ... as they come.

    Each file is written under a temporary name and renamed into place once complete; on error inside
    the ``with`` block the unfinished file is deleted. A folder's ``part-*.parquet`` files from an
    earlier run that this run did not rewrite are removed at close, so the folder holds this run only.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        rows_per_file: int | None = None,
        row_group_size: int = 128,
        skeleton: str = "t2m",
        feature_dim: int = 263,
    ) -> None:
        self.path = Path(path)
        self._single = self.path.suffix == ".parquet"
        if rows_per_file is not None and (self._single or rows_per_file < 1):
            raise ValueError("rows_per_file needs a folder path and a positive count")
        if row_group_size < 1:
            raise ValueError("row_group_size must be positive")
        self.rows_per_file = rows_per_file
        self.row_group_size = row_group_size
        self.skeleton = skeleton
        self.feature_dim = feature_dim
        self.files: list[Path] = []
        self.rows = 0
        self._buffer: list[MotionClip] = []
        self._writer: pq.ParquetWriter | None = None
        self._tmp: Path | None = None
        self._rows_in_file = 0
        self._closed = False

    def __enter__(self) -> ParquetCorpusWriter:
        return self

    def __exit__(self, exc_type: type | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def write(self, clip: MotionClip) -> None:
        if self._closed:
            raise ValueError(f"{self.path}: writer is closed")
        self._buffer.append(clip)  # checked by clips_to_table when its row group is flushed
        room = self.row_group_size
        if self.rows_per_file is not None:
            room = min(room, self.rows_per_file - self._rows_in_file)
        if len(self._buffer) >= room:
            self._flush()

    def write_all(self, clips: Iterable[MotionClip]) -> None:
        for clip in clips:
            self.write(clip)

    def close(self) -> list[Path]:
        """Flush, publish the last file and drop stale parts; returns the files written."""
        if self._closed:
            return self.files
        self._flush()
        if self._writer is None and not self.files:
            self._open_file()  # an empty corpus is still a readable file with the schema
        if self._writer is not None:
            self._publish()
        if not self._single:
            for stale in set(self.path.glob(PART_PATTERN)) - set(self.files):
                stale.unlink()
        self._closed = True
        return self.files

    def abort(self) -> None:
        """Drop the unfinished file; files already published stay."""
        if self._writer is not None:
            self._writer.close()
            self._tmp.unlink(missing_ok=True)
            self._writer = None
        self._buffer = []
        self._closed = True

    def _flush(self) -> None:
        if not self._buffer:
            return
        if self._writer is None:
            self._open_file()
        table = clips_to_table(self._buffer, self.skeleton, self.feature_dim)
        self._writer.write_table(table, row_group_size=len(self._buffer))
        self._rows_in_file += len(self._buffer)
        self.rows += len(self._buffer)
        self._buffer = []
        if self.rows_per_file is not None and self._rows_in_file >= self.rows_per_file:
            self._publish()

    def _final_path(self) -> Path:
        return self.path if self._single else self.path / f"part-{len(self.files):05d}.parquet"

    def _open_file(self) -> None:
        final = self._final_path()
        final.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = temp_path_for(final)
        self._writer = pq.ParquetWriter(self._tmp, corpus_schema(self.skeleton, self.feature_dim), **WRITE_OPTIONS)

    def _publish(self) -> None:
        final = self._final_path()
        self._writer.close()
        os.replace(self._tmp, final)
        self.files.append(final)
        self._writer, self._tmp, self._rows_in_file = None, None, 0
