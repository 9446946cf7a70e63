"""What a run writes: the Arrow schema of output shards and the JSON records beside them.

Shards are plain Arrow columns (no extension types) so pyarrow, pandas and duckdb read them as-is, one file or the
whole ``shards/`` folder (``pd.read_parquet(run / "shards")``; ``style`` is dictionary-encoded so the
``style=<name>`` folders, read as a hive partition, merge with the column). ``motion`` is flattened row-major:
``np.asarray(row.motion).reshape(row.n_frames, row.n_feats)``. ``motionaug.augment.outputs.run_dir.RunDir`` reads
and writes the run folder and documents its layout.
"""

from __future__ import annotations

import pyarrow as pa
from pydantic import BaseModel, ConfigDict, Field

from motionaug.schemas.corpus import CAPTION_TYPE

SHARD_SCHEMA_VERSION = 1
META_SHARD_VERSION = b"motionaug.shard_schema_version"

ARTIFACT_REF_TYPE = pa.struct(
    [pa.field("path", pa.string(), nullable=False), pa.field("sha256", pa.string(), nullable=False)]
)

SHARD_FIELDS = [
    pa.field("run_id", pa.string(), nullable=False),
    pa.field("source_id", pa.string(), nullable=False),
    pa.field("output_id", pa.string(), nullable=False),  # <source_id>__<style>, filename safe
    # dictionary-typed so it merges with the ``style=<name>`` folder that pyarrow/pandas read as a hive partition
    pa.field("style", pa.dictionary(pa.int32(), pa.string()), nullable=False),
    pa.field("method", pa.string(), nullable=False),
    pa.field("motion", pa.list_(pa.float32()), nullable=False),  # (n_frames * n_feats,) row-major
    pa.field("n_frames", pa.int32(), nullable=False),
    pa.field("n_feats", pa.int32(), nullable=False),
    pa.field("fps", pa.float32(), nullable=False),
    pa.field("original_captions", pa.list_(CAPTION_TYPE), nullable=False),
    pa.field("captions", pa.list_(CAPTION_TYPE), nullable=False),  # revised
    pa.field("content", pa.string()),
    pa.field("split", pa.string()),
    pa.field("seed", pa.int64(), nullable=False),
    pa.field("artifact_ref", ARTIFACT_REF_TYPE, nullable=False),
    pa.field("scores", pa.map_(pa.string(), pa.float64())),
]


def shard_schema() -> pa.Schema:
    return pa.schema(SHARD_FIELDS, metadata={META_SHARD_VERSION: str(SHARD_SCHEMA_VERSION).encode()})


def output_id(source_id: str, style: str) -> str:
    """Deterministic, filename-safe id of a stylized clip."""
    return f"{source_id}__{style}"


class _Record(BaseModel):
    """A JSON record of a run folder. Top-level records carry ``version``, their format: ``RunDir`` refuses another."""

    model_config = ConfigDict(extra="forbid")


class PlanUnit(_Record):
    unit: int
    ids: list[str]
    files: list[str] = Field(description="Source files (HumanML3D parent ids) to read the unit's clips from.")
    styles: dict[str, list[str]] = Field(description="Per style, the ids of this unit it is applied to.")


class Plan(_Record):
    version: int = 1
    run_id: str
    n_clips: int
    unit_size: int
    units: list[PlanUnit]
    splits: dict[str, str] = Field(default_factory=dict, description="Source id -> split, where known.")
    rejects: int = 0
    pool: list[str] = Field(default_factory=list, description="Content clip ids a method's prepare learns from.")
    pool_files: list[str] = Field(default_factory=list, description="Source files of the pool's clips.")
    in_place: int | None = Field(default=None, description="Chosen clips that stay in place (None: not counted).")


class ArtifactMarker(_Record):
    """``styles/<style>.done``: the artefact folder is complete and has this checksum."""

    version: int = 1
    style: str
    method: str
    path: str = Field(description="Artefact folder relative to the run folder (what sha256 covers).")
    entry: str = Field(default="", description="Sub-folder of path that prepare returned, if any.")
    sha256: str
    files: int
    seconds: float
    trained_sha256: str | None = Field(
        default=None, description="Checksum of the method's once-per-run models it was made with (None: none)."
    )


class ShardMarker(_Record):
    """``_unit-<n>.done``: the shard (and its rejects file) is complete."""

    version: int = 1
    style: str
    unit: int
    path: str = Field(description="Shard file relative to the run folder.")
    rows: int
    rejects: int
    sha256: str
    artifact_sha256: str = Field(default="", description="Checksum of the style artefact the rows were made with.")
    trained_sha256: str | None = Field(default=None, description="Checksum of the once-per-run models (None: none).")
    seconds: float
    load_seconds: float = 0.0
    peak_rss_mb: float = Field(default=0.0, description="Peak resident memory of the worker process so far.")
    score_sums: dict[str, float] = Field(default_factory=dict)
    score_counts: dict[str, int] = Field(default_factory=dict)


class StageTiming(_Record):
    seconds: float
    tasks: int
    skipped: int = 0


class Manifest(_Record):
    version: int = 1
    run_id: str
    config: dict
    code_version: str
    method: str
    artifacts: dict[str, ArtifactMarker]
    shards: list[ShardMarker]
    rows: int
    rejects: int
    stages: dict[str, StageTiming]
    scores: dict[str, float] = Field(default_factory=dict, description="Mean of each score over all rows.")
    base_models: str | None = None
