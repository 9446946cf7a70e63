"""Verified reads: a shard is used only when its bytes still have the sha256 the run recorded for it.

Export, evaluation and previews read shards through ``verified_shards``, so a flipped bit is one clear error
naming the shard instead of silently different motion. ``motionaug run`` on the same folder repairs it: the
transfer stage's done-check compares the same checksum and redoes the unit.
"""

from __future__ import annotations

from pathlib import Path

from motionaug.augment.outputs.checksums import sha256_file
from motionaug.augment.outputs.run_dir import RunDir
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.shards import ShardMarker

REPAIR = "run `motionaug run` again on this folder to repair it"


def verified_shards(run: RunDir, complete: bool = True, style: str | None = None) -> list[Path]:
    """Shard files of ``run`` (of one ``style`` if given), each checked against its recorded sha256.

    ``complete``: the run must be finished and the manifest's shard list is the truth (export, evaluate);
    otherwise (previews of a run in progress) the manifest when there is one, else the shard markers.
    """
    markers = _recorded_markers(run, complete)
    if style is not None:
        markers = [m for m in markers if m.style == style]
    return [_checked(run, marker) for marker in sorted(markers, key=lambda m: m.path)]


def _recorded_markers(run: RunDir, complete: bool) -> list[ShardMarker]:
    if complete or run.success_path.is_file():
        return run.manifest().shards
    return run.shard_markers()


def _checked(run: RunDir, marker: ShardMarker) -> Path:
    path = run.root / marker.path
    if not path.is_file():
        raise MotionDataError(str(path), f"shard is missing; {REPAIR}")
    if sha256_file(path) != marker.sha256:
        raise MotionDataError(str(path), f"checksum mismatch; {REPAIR}")
    return path
