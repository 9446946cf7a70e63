"""Arrow schema of the Parquet corpus and the summary model ``corpus inspect`` prints.

The corpus is plain Arrow columns, no extension types, so pyarrow, pandas and duckdb read the files as-is.
A clip's motion is stored flattened row-major: ``np.asarray(row.motion).reshape(row.n_frames, row.n_feats)``.
"""

from __future__ import annotations

import pyarrow as pa
from pydantic import BaseModel, ConfigDict, Field

CORPUS_SCHEMA_VERSION = 1

META_SCHEMA_VERSION = b"motionaug.schema_version"
META_SKELETON = b"motionaug.skeleton"
META_FEATURE_DIM = b"motionaug.feature_dim"

CAPTION_TYPE = pa.struct(
    [
        pa.field("text", pa.string(), nullable=False),
        pa.field("tokens", pa.list_(pa.string()), nullable=False),
        pa.field("start", pa.float32(), nullable=False),
        pa.field("end", pa.float32(), nullable=False),
    ]
)

CORPUS_FIELDS = [
    pa.field("id", pa.string(), nullable=False),
    pa.field("motion", pa.list_(pa.float32()), nullable=False),  # (n_frames * n_feats,) row-major
    pa.field("n_frames", pa.int32(), nullable=False),
    pa.field("n_feats", pa.int32(), nullable=False),
    pa.field("fps", pa.float32(), nullable=False),
    pa.field("captions", pa.list_(CAPTION_TYPE), nullable=False),
    pa.field("content", pa.string()),
    pa.field("style", pa.string()),
    pa.field("source", pa.string(), nullable=False),
    pa.field("split", pa.string()),
    pa.field("meta", pa.map_(pa.string(), pa.string())),  # MotionClip.meta without "split"
]


def corpus_schema(skeleton: str = "t2m", feature_dim: int = 263) -> pa.Schema:
    """The corpus schema, with the version, skeleton and feature width in its metadata."""
    return pa.schema(
        CORPUS_FIELDS,
        metadata={
            META_SCHEMA_VERSION: str(CORPUS_SCHEMA_VERSION).encode(),
            META_SKELETON: skeleton.encode(),
            META_FEATURE_DIM: str(feature_dim).encode(),
        },
    )


class CorpusInfo(BaseModel):
    """What a corpus holds, counted in one streaming pass."""

    model_config = ConfigDict(extra="forbid")

    format: str = Field(description="'humanml3d' or 'parquet'.")
    path: str
    clips: int = 0
    frames: int = 0
    hours: float = 0.0
    captions: int = 0
    contents: dict[str, int] = Field(default_factory=dict, description="Clips per content label.")
    styles: dict[str, int] = Field(default_factory=dict, description="Clips per style label.")
    splits: dict[str, int] = Field(default_factory=dict, description="Clips per split name.")
    rejects: int = 0
    schema_version: int | None = None
    skeleton: str | None = None
    feature_dim: int | None = None
