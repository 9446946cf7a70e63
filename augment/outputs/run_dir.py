"""One run folder, read and written through one type by the pipeline, evaluation, export and previews.

A unit of work is done when its marker exists and the checksum in it matches what it names; anything else is redone
under the same name. Records are published with fsync (file, then folder), so a marker never outlives what it names
across a power loss. A record of another format ``version`` is refused, never silently redone over. ``_LOCK``
(``run_lock.RunLock``) says which process writes the folder. ``RunDir`` documents the layout.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any, TypeVar

import pyarrow as pa
import pyarrow.parquet as pq
from pydantic import BaseModel

from motionaug.augment.io import atomic_write_text
from motionaug.augment.outputs.checksums import sha256_file, sha256_tree
from motionaug.augment.outputs.run_lock import LOCK_FILE
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.shards import ArtifactMarker, Manifest, Plan, ShardMarker

TMP_SUFFIX = ".tmp"
R = TypeVar("R", bound=BaseModel)


def dump_json(path: Path, data: dict) -> None:
    atomic_write_text(path, json.dumps(data, indent=1, sort_keys=True, default=str) + "\n", fsync=True)


def write_record(record: BaseModel, path: Path) -> None:
    atomic_write_text(path, record.model_dump_json(indent=1) + "\n", fsync=True)


def check_version(path: Path, data: object, kind: type[BaseModel]) -> None:
    """Refuse a record whose format ``version`` is not the one ``kind`` reads (a folder of another motionaug)."""
    field = kind.model_fields.get("version")
    if field is None or not isinstance(data, dict) or "version" not in data:
        return
    if data["version"] != field.default:
        reason = f"format version {data['version']}, this motionaug reads {field.default}"
        raise MotionDataError(str(path), f"{reason}; use the motionaug that wrote it, or another --out")


def read_record(path: Path, kind: type[R]) -> R | None:
    """The record, or None when absent or unreadable (a torn or corrupt file means 'not done', and is redone);
    one error when it is of another format version."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    check_version(path, data, kind)
    try:
        return kind.model_validate(data)
    except ValueError:
        return None


SCORES_FILE = "scores.parquet"
CONTENT_SCORE = "content_score"


class RunDir:
    """Paths and records of one run folder.

    Layout (the records are the pydantic models of ``motionaug.schemas.shards``)::

        config.resolved.json  plan.json  manifest.json  _SUCCESS  _LOCK (while a run writes it)
        trained/...                                      (the method's once-per-run artefact, when it has one)
        styles/<style>/...  styles/<style>.done          (a style's artefact + its marker)
        shards/style=<style>/unit-00003.parquet  _unit-00003.done   (markers start with "_": dataset readers skip them)
        rejects/style=<style>/unit-00003.jsonl
    """

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)

    # ---- paths ----------------------------------------------------------------------------------

    config_path = property(lambda self: self.root / "config.resolved.json")
    plan_path = property(lambda self: self.root / "plan.json")
    manifest_path = property(lambda self: self.root / "manifest.json")
    scores_path = property(lambda self: self.root / SCORES_FILE)
    success_path = property(lambda self: self.root / "_SUCCESS")
    trained_dir = property(lambda self: self.root / "trained")
    styles_dir = property(lambda self: self.root / "styles")
    shards_dir = property(lambda self: self.root / "shards")
    rejects_dir = property(lambda self: self.root / "rejects")

    def artifact_dir(self, style: str) -> Path:
        return self.styles_dir / style

    def artifact_marker_path(self, style: str) -> Path:
        return self.styles_dir / f"{style}.done"

    def shard_path(self, style: str, unit: int) -> Path:
        return self.shards_dir / f"style={style}" / f"unit-{unit:05d}.parquet"

    def shard_marker_path(self, style: str, unit: int) -> Path:
        return self.shards_dir / f"style={style}" / f"_unit-{unit:05d}.done"

    def rejects_path(self, style: str, unit: int) -> Path:
        return self.rejects_dir / f"style={style}" / f"unit-{unit:05d}.jsonl"

    def shard_files(self) -> list[Path]:
        return sorted(self.shards_dir.glob("style=*/unit-*.parquet"))

    # ---- the resolved config ------------------------------------------------------------------------

    def write_config(self, run_id: str, config: dict[str, Any]) -> None:
        dump_json(self.config_path, {"run_id": run_id, "config": config})

    def recorded_run_id(self) -> str | None:
        """The run id this folder holds, or None when it is not (yet) a run folder."""
        try:
            return json.loads(self.config_path.read_text(encoding="utf-8"))["run_id"]
        except (OSError, ValueError, KeyError, TypeError):
            return None

    def is_run(self) -> bool:
        return self.recorded_run_id() is not None

    def config(self) -> dict[str, Any]:
        """The run's resolved config (a dict: the code reading it may be older or newer than the run)."""
        try:
            return json.loads(self.config_path.read_text(encoding="utf-8"))["config"]
        except (OSError, ValueError, KeyError) as err:
            reason = f"not a motionaug run folder (no readable {self.config_path.name}: {str(err).splitlines()[0]})"
            raise MotionDataError(str(self.root), reason) from None

    def styles(self) -> list[str]:
        return [s["name"] for s in self.config().get("styles", [])]

    # ---- plan, markers, manifest ------------------------------------------------------------------

    def read_plan(self) -> Plan | None:
        return read_record(self.plan_path, Plan)

    def write_plan(self, plan: Plan) -> None:
        dump_json(self.plan_path, plan.model_dump(mode="json"))

    def artifact(self, style: str) -> ArtifactMarker | None:
        """The style's marker when its artefact folder still has the recorded checksum; None: redo it."""
        marker = read_record(self.artifact_marker_path(style), ArtifactMarker)
        if marker is None:
            return None
        folder = self.root / marker.path
        return marker if folder.is_dir() and sha256_tree(folder) == (marker.sha256, marker.files) else None

    def shard(self, style: str, unit: int) -> ShardMarker | None:
        """The unit's marker when its shard still has the recorded checksum; None: redo it."""
        marker = read_record(self.shard_marker_path(style, unit), ShardMarker)
        if marker is None:
            return None
        shard = self.root / marker.path
        return marker if shard.is_file() and sha256_file(shard) == marker.sha256 else None

    def shard_markers(self) -> list[ShardMarker]:
        """Every shard marker present, unverified (cheap: for status)."""
        markers = (read_record(p, ShardMarker) for p in sorted(self.shards_dir.glob("style=*/_unit-*.done")))
        return [m for m in markers if m is not None]

    def write_manifest(self, manifest: Manifest) -> None:
        """The manifest, then ``_SUCCESS``: the run is complete."""
        dump_json(self.manifest_path, manifest.model_dump(mode="json"))
        atomic_write_text(self.success_path, "", fsync=True)

    def manifest(self) -> Manifest:
        """The manifest of a complete run; one clear error otherwise."""
        if not self.success_path.is_file() or not self.manifest_path.is_file():
            reason = "run is not complete (no _SUCCESS); finish it with `motionaug run` first"
            raise MotionDataError(str(self.root), reason)
        try:
            data = json.loads(self.manifest_path.read_text(encoding="utf-8"))
            check_version(self.manifest_path, data, Manifest)
            return Manifest.model_validate(data)
        except MotionDataError:
            raise
        except ValueError as err:
            raise MotionDataError(
                str(self.manifest_path), f"unreadable manifest ({str(err).splitlines()[0]})"
            ) from None

    # ---- temporaries --------------------------------------------------------------------------------

    def content_scores(self) -> dict[str, float] | None:
        """output_id -> content score from ``scores.parquet``; None when the run has not been evaluated."""
        path = self.scores_path
        if not path.is_file():
            return None
        try:
            table = pq.read_table(path, columns=["output_id", CONTENT_SCORE])
        except (OSError, pa.ArrowInvalid, KeyError) as err:
            raise MotionDataError(str(path), f"unreadable scores file ({str(err).splitlines()[0]})") from None
        pairs = zip(table["output_id"].to_pylist(), table[CONTENT_SCORE].to_pylist())
        return {oid: float(score) for oid, score in pairs if score is not None}

    def clear(self) -> None:
        """Delete everything the folder holds but its lock (``--force``: start over, still as the one writer)."""
        for path in self.root.iterdir():
            if path.name == LOCK_FILE:
                continue
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path)
            else:
                path.unlink()

    def sweep_temporaries(self) -> list[Path]:
        """Remove ``*.tmp`` files and folders a killed process left behind; returns what was removed.

        Call it holding the run lock only: then every temporary is a dead writer's, never a live run's."""
        removed = []
        for path in sorted(self.root.rglob(f"*{TMP_SUFFIX}"), key=lambda p: -len(p.parts)):
            if path.is_dir():
                shutil.rmtree(path, ignore_errors=True)
            else:
                path.unlink(missing_ok=True)
            removed.append(path)
        return removed
