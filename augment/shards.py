"""Output shards and completion markers: written atomically, verified by checksum, read back as rows.

A unit of work is done when its marker exists and the checksum in it matches the file it names; a
shard without a marker (a crash between rename and marker) is simply redone, overwriting the same name.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from schemas.errors import MotionDataError
from augment.io import atomic_path, atomic_write_text
from augment.methods.base import TransferOutput
from schemas.captions import Caption
from schemas.shards import ArtifactMarker, ShardMarker, output_id, shard_schema

WRITE_OPTIONS = {"compression": "zstd"}
TMP_SUFFIX = ".tmp"


def sha256_file(path: Path, chunk: int = 1 << 20) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        while block := handle.read(chunk):
            digest.update(block)
    return digest.hexdigest()


def sha256_tree(folder: Path) -> tuple[str, int]:
    """(checksum over relative paths and contents of every file, file count), independent of walk order."""
    digest = hashlib.sha256()
    files = sorted(p for p in Path(folder).rglob("*") if p.is_file())
    for path in files:
        digest.update(path.relative_to(folder).as_posix().encode() + b"\0" + sha256_file(path).encode())
    return digest.hexdigest(), len(files)


def _captions(captions: Sequence[Caption]) -> list[dict]:
    return [{"text": c.text, "tokens": list(c.tokens), "start": c.start, "end": c.end} for c in captions]


def output_row(
    out: TransferOutput, source_captions: Sequence[Caption], context: dict, content: str | None, split: str | None
) -> dict:
    """One shard row; ``context`` carries run_id, method, fps, seed and artifact_ref."""
    motion = np.ascontiguousarray(out.motion, dtype=np.float32)
    return {
        "run_id": context["run_id"], "source_id": out.source_id, "output_id": output_id(out.source_id, out.style),
        "style": out.style, "method": context["method"], "motion": motion.reshape(-1),
        "n_frames": motion.shape[0], "n_feats": motion.shape[1], "fps": context["fps"],
        "original_captions": _captions(source_captions), "captions": _captions(out.captions),
        "content": content, "split": split, "seed": context["seed"], "artifact_ref": context["artifact_ref"],
        "scores": sorted((k, float(v)) for k, v in out.scores.items()),
    }  # fmt: skip


def rows_to_table(rows: Sequence[dict]) -> pa.Table:
    schema = shard_schema()
    columns = {f.name: [row[f.name] for row in rows] for f in schema}
    columns["motion"] = pa.array(columns["motion"], type=pa.list_(pa.float32()))
    return pa.Table.from_pydict(columns, schema=schema)


def write_shard(rows: Sequence[dict], path: Path) -> str:
    """Write rows to ``path`` via a temporary file renamed into place; returns the file's sha256."""
    with atomic_path(path) as tmp:
        pq.write_table(rows_to_table(rows), tmp, **WRITE_OPTIONS)
    return sha256_file(path)


def write_marker(marker: ShardMarker | ArtifactMarker, path: Path) -> None:
    atomic_write_text(path, marker.model_dump_json(indent=1) + "\n")


def read_marker(path: Path, kind: type[ShardMarker] | type[ArtifactMarker]) -> ShardMarker | ArtifactMarker | None:
    """The marker, or None when absent or unreadable (a torn or foreign file means 'not done')."""
    try:
        return kind.model_validate_json(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def verified_shard(run_dir: Path, marker_path: Path) -> ShardMarker | None:
    """The marker when it exists and its shard's checksum matches; None means 'do it again'."""
    marker = read_marker(marker_path, ShardMarker)
    if marker is None:
        return None
    shard = run_dir / marker.path
    return marker if shard.is_file() and sha256_file(shard) == marker.sha256 else None


def verified_artifact(run_dir: Path, marker_path: Path) -> ArtifactMarker | None:
    marker = read_marker(marker_path, ArtifactMarker)
    if marker is None:
        return None
    folder = run_dir / marker.path
    return marker if folder.is_dir() and sha256_tree(folder) == (marker.sha256, marker.files) else None


def publish_dir(tmp_dir: Path, final: Path) -> None:
    """Move a finished folder into place, replacing an unverified leftover of an earlier attempt."""
    if final.exists():
        shutil.rmtree(final)
    os.replace(tmp_dir, final)


def sweep_temporaries(root: Path) -> list[Path]:
    """Remove ``*.tmp`` files and folders a killed process left behind; returns what was removed."""
    removed = []
    for path in sorted(Path(root).rglob(f"*{TMP_SUFFIX}"), key=lambda p: -len(p.parts)):
        if path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)
        removed.append(path)
    return removed


def shard_files(run_dir: Path) -> list[Path]:
    return sorted((Path(run_dir) / "shards").glob("style=*/unit-*.parquet"))


def iter_shard_rows(run_dir: Path, columns: list[str] | None = None, batch_size: int = 64) -> Iterator[dict]:
    """Rows of every published shard as Python dicts, one record batch in memory at a time."""
    for file in shard_files(run_dir):
        parquet = pq.ParquetFile(file)
        if parquet.schema_arrow.remove_metadata() != shard_schema().remove_metadata():
            raise MotionDataError(str(file), "not a motionaug shard (schema differs)")
        for batch in parquet.iter_batches(batch_size=batch_size, columns=columns):
            yield from batch.to_pylist()


def row_motion(row: dict) -> np.ndarray:
    return np.asarray(row["motion"], dtype=np.float32).reshape(row["n_frames"], row["n_feats"])


def row_captions(row: dict, key: str = "captions") -> list[Caption]:
    return [Caption(**c) for c in row[key]]


def dump_json(path: Path, data: dict) -> None:
    atomic_write_text(path, json.dumps(data, indent=1, sort_keys=True, default=str) + "\n")
