"""Clips a reader skipped, with where and why, kept as JSON lines beside the outputs."""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from pydantic import BaseModel, ConfigDict

from motionaug.augment.io import atomic_open
from motionaug.schemas.errors import MotionDataError


class Reject(BaseModel):
    """One skipped clip: its id (as found, possibly unsafe), the file at fault and the reason."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    id: str
    source: str
    reason: str

    @classmethod
    def from_error(cls, clip_id: str, err: MotionDataError) -> Reject:
        return cls(id=clip_id, source=err.source, reason=err.reason)

    def __str__(self) -> str:
        return f"{self.source}: {self.reason} (clip {self.id})"


def write_rejects(rejects: Iterable[Reject], path: str | os.PathLike[str]) -> int:
    """Write one JSON object per line, atomically; returns how many were written."""
    count = 0
    with atomic_open(path, "w") as handle:
        for reject in rejects:
            handle.write(reject.model_dump_json() + "\n")
            count += 1
    return count


def read_rejects(path: str | os.PathLike[str]) -> list[Reject]:
    lines = Path(path).read_text(encoding="utf-8").splitlines()
    return [Reject.model_validate_json(line) for line in lines if line.strip()]
