"""The run's stages, datatrove-style: each a small class with a name, a resource request and one ``run``.

Stages never import Ray; the executor (``workflows.ray_executor``) decides where each runs. Every stage
writes under a deterministic name (temporary file renamed into place, then a completion marker), so a
re-run skips verified work and redoes the rest, and the final row set never depends on interruptions.

    plan        -> plan.json (unit -> clip ids; ids only, the corpus is streamed)
    base_models -> pre-trained base models, when the method needs them
    finetune    -> styles/<style>/ + styles/<style>.done          (one task per style)
    transfer    -> shards/style=<s>/unit-<n>.parquet + .done      (one task per unit x style)
    manifest    -> manifest.json + _SUCCESS
"""

from __future__ import annotations

import hashlib
import json
import re
import resource
import subprocess
import time
import uuid
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from pydantic import ValidationError

from augment.clip import MotionClip
from augment.corpus import HumanML3DReader, Reject, detect_format, open_corpus, write_rejects
from augment.corpus.parquet import parquet_files, table_to_clips
from schemas.errors import MotionDataError, first_error
from augment.export import split_of_ids
from augment.methods.base import StyleModel, TransferOutput
from augment.methods.registry import create_method, needs_base_models, validate_method_params
from augment.shards import (
    dump_json,
    output_row,
    publish_dir,
    sha256_tree,
    verified_artifact,
    verified_shard,
    write_marker,
    write_shard,
)
from schemas.shards import ArtifactMarker, Manifest, Plan, PlanUnit, RunLayout, ShardMarker, StageTiming
from schemas.run_config import RunConfig
from schemas.styles import StyleSpec

CORPUS_REJECTS = "corpus.jsonl"
SPAN_ID = re.compile(r"^(?P<parent>.+)_\d{4,}_\d{4,}$")


@dataclass(frozen=True)
class Resources:
    cpus: float = 1.0
    gpus: float = 0.0


def derive_seed(*parts: object) -> int:
    """A stable 63-bit seed from any parts (``hash()`` is salted per process, so it cannot be used)."""
    digest = hashlib.sha256(":".join(str(p) for p in parts).encode()).digest()
    return int.from_bytes(digest[:8], "little") >> 1


# ---- config checks -------------------------------------------------------------------------------


def check_config(config: RunConfig) -> None:
    """Everything checkable before Ray starts: corpus, example files, method and its params."""
    path = config.corpus.path
    if not path.exists():
        raise MotionDataError("config corpus.path", f"{path} not found")
    found = detect_format(path)
    if config.corpus.format not in ("auto", found):
        raise MotionDataError("config corpus.format", f"{config.corpus.format!r} given, but {path} is {found}")
    for i, style in enumerate(config.styles):
        for j, example in enumerate(style.examples):
            source = Path(example.source)
            if source.suffix.lower() in (".npy", ".bvh") and not source.is_file():
                raise MotionDataError(f"config styles[{i}].examples[{j}].source", f"style example file {source} not found")
    validate_method_params(config.method.name, config.method.params)
    if needs_base_models(config.method.name) and config.base_models.pretrain:
        pretrain_config(config)


def pretrain_config(config: RunConfig) -> Any:
    """The pre-training config of the run's base models: the size's preset plus ``base_models.pretrain``."""
    from augment.pretrain import PretrainConfig

    try:
        return PretrainConfig.for_size(config.base_models.size, seed=config.seed, **config.base_models.pretrain)
    except ValidationError as err:
        field, message = first_error(err, "")
        raise MotionDataError(f"config base_models.pretrain.{field}", message) from None


# ---- corpus access -------------------------------------------------------------------------------


class _FilesReader(HumanML3DReader):
    """A HumanML3D reader over named source files only (a unit's), instead of a whole split file."""

    def __init__(self, root: Path, files: Sequence[str], **options: Any) -> None:
        super().__init__(root, split=None, **options)
        self._files = list(files)

    def _entries(self) -> Iterator[tuple[str, str]]:
        for file_id in self._files:
            yield file_id, str(self.root / "new_joint_vecs" / f"{file_id}.npy")


def _file_of(clip: MotionClip, fmt: str, parquet_file: str | None) -> str:
    if fmt == "parquet":
        return parquet_file or ""
    return clip.meta.get("parent", clip.id)


def iter_corpus(config: RunConfig, rejects: list[Reject]) -> Iterator[tuple[MotionClip, str]]:
    """(clip, source file key) for every readable clip, streamed; clips the reader skips go to ``rejects``."""
    path = config.corpus.path
    if detect_format(path) == "parquet":
        for file in parquet_files(path):
            for batch in pq.ParquetFile(file).iter_batches(batch_size=64):
                for clip in table_to_clips(pa.Table.from_batches([batch]), source=str(file)):
                    yield clip, file.name
        return
    options = {} if config.corpus.split is None else {"split": config.corpus.split}
    reader = open_corpus(path, **options)
    for clip in reader:
        yield clip, clip.meta.get("parent", clip.id)
    rejects.extend(reader.rejects)


def load_clips(config: RunConfig, files: Sequence[str], ids: Sequence[str]) -> tuple[list[MotionClip], list[Reject]]:
    """The clips ``ids`` (in that order) read from their source ``files``; a missing id becomes a Reject."""
    wanted = set(ids)
    path = config.corpus.path
    found: dict[str, MotionClip] = {}
    rejects: list[Reject] = []
    if detect_format(path) == "parquet":
        folder = path if path.is_dir() else path.parent
        for name in files:
            table = pq.read_table(folder / name, filters=[("id", "in", sorted(wanted))])
            found.update((c.id, c) for c in table_to_clips(table, source=str(folder / name)))
    else:
        reader = _FilesReader(path, files)
        found.update((c.id, c) for c in reader if c.id in wanted)
        rejects.extend(r for r in reader.rejects if r.id in wanted)
    rejected = {r.id for r in rejects}
    for clip_id in ids:
        if clip_id not in found and clip_id not in rejected:
            rejects.append(Reject(id=clip_id, source=str(path), reason="clip not found in the corpus any more"))
    return [found[i] for i in ids if i in found], rejects


def corpus_lookup(config: RunConfig, clip_id: str) -> MotionClip | None:
    """One clip by id (style examples given as corpus ids)."""
    match = SPAN_ID.match(clip_id)
    path = config.corpus.path
    if detect_format(path) == "parquet":
        files = [f.name for f in parquet_files(path)]
    else:
        candidates = {clip_id, match.group("parent") if match else clip_id}
        files = [f for f in sorted(candidates) if (path / "new_joint_vecs" / f"{f}.npy").is_file()]
    clips, _ = load_clips(config, files, [clip_id])
    return clips[0] if clips else None


def source_splits(config: RunConfig) -> dict[str, str]:
    """Source file id -> train/val/test from the split files of a HumanML3D corpus (empty for Parquet)."""
    root = config.corpus.path
    return split_of_ids(root) if detect_format(root) == "humanml3d" else {}


def keep_clip(clip: MotionClip, config: RunConfig) -> bool:
    """The corpus filters of the config."""
    f = config.corpus.filters
    if f.contents is not None and clip.content not in f.contents:
        return False
    if f.source_styles is not None and clip.style not in f.source_styles:
        return False
    if f.min_frames is not None and clip.n_frames < f.min_frames:
        return False
    if f.max_frames is not None and clip.n_frames > f.max_frames:
        return False
    if f.caption_regex is not None and not any(re.search(f.caption_regex, c.text) for c in clip.captions):
        return False
    return True


def styles_for(clip_id: str, styles: Sequence[str], per_clip: str | int, seed: int) -> list[str]:
    """The styles a clip is stylized in: all, or ``per_clip`` of them drawn deterministically per clip."""
    if per_clip == "all":
        return list(styles)
    rng = np.random.default_rng(derive_seed("fan_out", seed, clip_id))
    chosen = set(rng.choice(len(styles), size=int(per_clip), replace=False).tolist())
    return [s for i, s in enumerate(styles) if i in chosen]


# ---- stages ----------------------------------------------------------------------------------


class PlanStage:
    """Select clips (filters), split into units of ``unit_size`` ids in a seeded order; write plan.json."""

    name = "plan"

    def __init__(self, config: RunConfig) -> None:
        self.config = config
        self.layout = RunLayout(config.output)

    def resources(self) -> Resources:
        return Resources(cpus=1.0)

    def run(self) -> Plan:
        existing = self._existing()
        if existing is not None:
            return existing
        config = self.config
        chosen: list[tuple[str, str, str | None]] = []  # (id, file, split)
        file_splits = source_splits(config)
        all_ids: set[str] = set()
        rejects: list[Reject] = []
        for clip, file_key in iter_corpus(config, rejects):
            all_ids.add(clip.id)
            if keep_clip(clip, config):
                split = clip.meta.get("split") or file_splits.get(clip.meta.get("parent", clip.id))
                chosen.append((clip.id, file_key, split))
        self._check_example_ids(all_ids)
        write_rejects(rejects, self.layout.rejects_dir / CORPUS_REJECTS)
        plan = self._units(sorted(chosen), len(rejects))
        dump_json(self.layout.plan, plan.model_dump(mode="json"))
        return plan

    def _existing(self) -> Plan | None:
        if not self.layout.plan.is_file():
            return None
        plan = Plan.model_validate_json(self.layout.plan.read_text(encoding="utf-8"))
        return plan if plan.run_id == self.config.run_id() and plan.unit_size == self.config.compute.unit_size else None

    def _check_example_ids(self, all_ids: set[str]) -> None:
        for i, style in enumerate(self.config.styles):
            for j, example in enumerate(style.examples):
                if Path(example.source).suffix.lower() not in (".npy", ".bvh") and example.source not in all_ids:
                    where = f"config styles[{i}].examples[{j}].source"
                    raise MotionDataError(where, f"clip id {example.source!r} is not in the corpus (nor a .npy/.bvh file)")

    def _units(self, chosen: list[tuple[str, str, str | None]], n_rejects: int) -> Plan:
        config = self.config
        order = np.random.default_rng(derive_seed("plan", config.seed)).permutation(len(chosen))
        size = config.compute.unit_size
        style_names = [s.name for s in config.styles]
        units = []
        for n, start in enumerate(range(0, len(chosen), size)):
            members = sorted(chosen[int(i)] for i in order[start : start + size])
            ids = [m[0] for m in members]
            per_style: dict[str, list[str]] = {s: [] for s in style_names}
            for clip_id in ids:
                for style in styles_for(clip_id, style_names, config.fan_out.per_clip, config.fan_out.seed):
                    per_style[style].append(clip_id)
            units.append(PlanUnit(unit=n, ids=ids, files=sorted({m[1] for m in members}), styles=per_style))
        splits = {m[0]: m[2] for m in chosen if m[2] is not None}
        return Plan(
            run_id=config.run_id(), n_clips=len(chosen), unit_size=size, units=units, splits=splits, rejects=n_rejects
        )


class BaseModelsStage:
    """Reuse the base models when present, else pre-train them (``augment.pretrain.ensure_base_models``)."""

    name = "base_models"

    def __init__(self, config: RunConfig) -> None:
        self.config = config

    def resources(self) -> Resources:
        return Resources(cpus=self.config.compute.finetune_cpus, gpus=self.config.compute.finetune_gpus)

    def target(self) -> Path:
        return self.config.base_models.path or (self.config.output / "base_models")

    def needed(self) -> bool:
        return needs_base_models(self.config.method.name)

    def run(self) -> str:
        target = self.target()
        if self.config.base_models.path is not None and (target / "base.json").is_file():
            return str(target)  # the user's own base models, used as they are
        if not self.config.base_models.pretrain_if_missing:
            if not target.is_dir():
                raise MotionDataError("config base_models.path", f"{target} not found and pretrain_if_missing is false")
            return str(target)
        from augment.pretrain import ensure_base_models

        config = pretrain_config(self.config)
        progress = PretrainLog()
        return str(ensure_base_models(self.config.corpus.path, target, config.size, config.seed, progress, config))


class PretrainLog:
    """Pre-training progress as a line per stage every 10% (Ray forwards a task's stdout to the driver)."""

    def __init__(self) -> None:
        self.started = time.perf_counter()
        self.last: dict[str, int] = {}

    def __call__(self, stage: str, step: int, total: int, metrics: dict[str, float]) -> None:
        tenth = min(10, step * 10 // max(total, 1))
        if tenth <= self.last.get(stage, 0) and step != 1:
            return
        self.last[stage] = tenth
        loss = f" loss {metrics['loss']:.4f}" if "loss" in metrics else ""
        print(f"pre-training {stage}: {step}/{total}{loss} ({time.perf_counter() - self.started:.0f} s)", flush=True)


def load_examples(style: StyleSpec, config: RunConfig) -> list[MotionClip]:
    """The style's validated example clips (corpus ids are looked up in the run's corpus)."""
    from augment.style_examples import load_style_examples

    return load_style_examples(style, lambda clip_id: corpus_lookup(config, clip_id))


class FinetuneStage:
    """One style: learn it from its examples, publish the artefact folder atomically, then its marker."""

    name = "finetune"

    def __init__(self, config: RunConfig, base_dir: str | None) -> None:
        self.config = config
        self.base_dir = base_dir
        self.layout = RunLayout(config.output)

    def resources(self) -> Resources:
        return Resources(cpus=self.config.compute.finetune_cpus, gpus=self.config.compute.finetune_gpus)

    def task_name(self, style: str) -> str:
        return f"finetune[style={style}]"

    def done(self, style: str) -> ArtifactMarker | None:
        return verified_artifact(self.layout.root, self.layout.artifact_marker(style))

    def run(self, style_name: str, sample: PlanUnit | None = None) -> ArtifactMarker:
        """``sample`` (a unit of the plan) is the content the method may draw from while it learns."""
        start = time.perf_counter()
        content = load_clips(self.config, sample.files, sample.ids)[0] if sample is not None else []
        style = next(s for s in self.config.styles if s.name == style_name)
        method = create_method(self.config.method.name, self.config.method.params)
        examples = load_examples(style, self.config)
        final = self.layout.artifact_dir(style_name)
        tmp = final.with_name(f".{style_name}.{uuid.uuid4().hex[:12]}.tmp")
        seed = derive_seed("finetune", self.config.seed, style_name)
        base = Path(self.base_dir) if self.base_dir else None
        returned = Path(method.prepare(style, examples, base, list(content), tmp, seed=seed))
        inner = returned.relative_to(tmp) if returned != tmp else Path()
        publish_dir(tmp, final)
        digest, files = sha256_tree(final)
        marker = ArtifactMarker(
            style=style_name, method=self.config.method.name, path=final.relative_to(self.layout.root).as_posix(),
            entry=inner.as_posix() if inner != Path() else "", sha256=digest, files=files,
            seconds=time.perf_counter() - start,
        )  # fmt: skip
        write_marker(marker, self.layout.artifact_marker(style_name))
        return marker


class TransferStage:
    """One (unit, style): load the artefact once, stylize the unit in batches, publish shard + rejects + marker."""

    name = "transfer"

    def __init__(self, config: RunConfig, base_dir: str | None) -> None:
        self.config = config
        self.base_dir = base_dir
        self.layout = RunLayout(config.output)

    def resources(self) -> Resources:
        return Resources(cpus=self.config.compute.transfer_cpus, gpus=self.config.compute.transfer_gpus)

    def task_name(self, style: str, unit: int) -> str:
        return f"transfer[style={style},unit={unit:04d}]"

    def done(self, style: str, unit: int) -> ShardMarker | None:
        return verified_shard(self.layout.root, self.layout.shard_marker(style, unit))

    def run(self, style: str, unit: PlanUnit, splits: dict[str, str], artifact: ArtifactMarker) -> ShardMarker:
        start = time.perf_counter()
        method = create_method(self.config.method.name, self.config.method.params)
        artifact_dir = self.layout.root / artifact.path / artifact.entry
        model = method.load(artifact_dir, Path(self.base_dir) if self.base_dir else None)
        load_seconds = time.perf_counter() - start
        clips, rejects = load_clips(self.config, unit.files, unit.styles[style])
        context = {
            "run_id": self.config.run_id(), "method": self.config.method.name, "fps": 20.0,
            "artifact_ref": {"path": artifact.path, "sha256": artifact.sha256},
        }  # fmt: skip
        rows: list[dict] = []
        size = self.config.compute.batch_size
        for b in range(0, len(clips), size):
            batch = clips[b : b + size]
            seed = derive_seed("transfer", self.config.seed, style, unit.unit, b // size)
            for clip, result in zip(batch, safe_transfer(model, batch, seed)):
                if isinstance(result, Reject):
                    rejects.append(result)
                    continue
                ctx = {**context, "fps": clip.fps, "seed": seed}
                rows.append(output_row(result, clip.captions, ctx, clip.content, splits.get(clip.id)))
        return self._publish(style, unit.unit, rows, rejects, start, load_seconds)

    def _publish(
        self, style: str, unit: int, rows: list[dict], rejects: list[Reject], start: float, load_seconds: float
    ) -> ShardMarker:
        shard = self.layout.shard(style, unit)
        digest = write_shard(rows, shard)
        write_rejects(rejects, self.layout.rejects(style, unit))
        sums: dict[str, float] = {}
        counts: dict[str, int] = {}
        for row in rows:
            for key, value in row["scores"]:
                sums[key] = sums.get(key, 0.0) + value
                counts[key] = counts.get(key, 0) + 1
        marker = ShardMarker(
            style=style, unit=unit, path=shard.relative_to(self.layout.root).as_posix(), rows=len(rows),
            rejects=len(rejects), sha256=digest, seconds=time.perf_counter() - start, load_seconds=load_seconds,
            peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, score_sums=sums, score_counts=counts,
        )  # fmt: skip
        write_marker(marker, self.layout.shard_marker(style, unit))
        return marker


def safe_transfer(model: StyleModel, batch: Sequence[MotionClip], seed: int) -> list[TransferOutput | Reject]:
    """The model's results, with any exception or malformed output turned into per-clip Rejects."""
    try:
        results = list(model.transfer(batch, seed=seed))
        if len(results) != len(batch):
            raise RuntimeError(f"method returned {len(results)} results for {len(batch)} clips")
    except Exception:  # noqa: BLE001 - one bad clip must not fail the unit: retry clip by clip
        results = [_transfer_one(model, clip, seed + i) for i, clip in enumerate(batch)]
    return [_checked(clip, result) for clip, result in zip(batch, results)]


def _transfer_one(model: StyleModel, clip: MotionClip, seed: int) -> TransferOutput | Reject:
    try:
        return list(model.transfer([clip], seed=seed))[0]
    except Exception as err:  # noqa: BLE001
        return Reject(id=clip.id, source=f"transfer {clip.id}", reason=f"{type(err).__name__}: {str(err)[:200]}")


def _checked(clip: MotionClip, result: TransferOutput | Reject) -> TransferOutput | Reject:
    if isinstance(result, Reject):
        return result
    motion = np.asarray(result.motion)
    if motion.ndim != 2 or motion.shape[1] != clip.motion.shape[1] or not np.isfinite(motion).all():
        reason = f"method output has shape {motion.shape} or non-finite values"
        return Reject(id=clip.id, source=f"transfer {clip.id}", reason=reason)
    if not result.captions:
        return Reject(id=clip.id, source=f"transfer {clip.id}", reason="method output has no captions")
    return result


# ---- manifest ----------------------------------------------------------------------------------


def code_version() -> str:
    """``git describe`` of the checkout when there is one, else the installed package version."""
    repo = Path(__file__).resolve().parents[1]
    try:
        out = subprocess.run(
            ["git", "-C", str(repo), "describe", "--always", "--dirty", "--tags"], capture_output=True, text=True, timeout=5
        )
        if out.returncode == 0 and out.stdout.strip():
            return f"git:{out.stdout.strip()}"
    except (OSError, subprocess.SubprocessError):
        pass
    from importlib.metadata import PackageNotFoundError, version

    try:
        return f"motionaug {version('motionaug')}"
    except PackageNotFoundError:
        return "unknown"


class ManifestStage:
    """Merge the per-unit markers into manifest.json, then write _SUCCESS (the run is complete)."""

    name = "manifest"

    def __init__(self, config: RunConfig) -> None:
        self.config = config
        self.layout = RunLayout(config.output)

    def run(
        self, plan: Plan, artifacts: dict[str, ArtifactMarker], shards: list[ShardMarker], stages: dict[str, StageTiming],
        base_models: str | None,
    ) -> Manifest:  # fmt: skip
        shards = sorted(shards, key=lambda m: (m.style, m.unit))
        sums: dict[str, float] = {}
        counts: dict[str, int] = {}
        for marker in shards:
            for key, value in marker.score_sums.items():
                sums[key] = sums.get(key, 0.0) + value
                counts[key] = counts.get(key, 0) + marker.score_counts.get(key, 0)
        manifest = Manifest(
            run_id=self.config.run_id(), config=self.config.model_dump(mode="json"), code_version=code_version(),
            method=self.config.method.name, artifacts=artifacts, shards=shards, rows=sum(m.rows for m in shards),
            rejects=plan.rejects + sum(m.rejects for m in shards), stages=stages,
            scores={k: sums[k] / counts[k] for k in sorted(sums) if counts.get(k)}, base_models=base_models,
        )  # fmt: skip
        dump_json(self.layout.manifest, manifest.model_dump(mode="json"))
        self.layout.success.write_text("", encoding="utf-8")
        return manifest


def write_resolved_config(config: RunConfig) -> None:
    layout = RunLayout(config.output)
    data = {"run_id": config.run_id(), "config": config.model_dump(mode="json")}
    dump_json(layout.config, data)


def recorded_run_id(run_dir: Path) -> str | None:
    path = RunLayout(run_dir).config
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text(encoding="utf-8"))["run_id"]
    except (ValueError, KeyError):
        return None


# ---- status ------------------------------------------------------------------------------------


@dataclass
class RunStatus:
    run_dir: Path
    run_id: str | None
    planned: bool
    clips: int
    styles_done: int
    styles_total: int
    shards_done: int
    shards_total: int
    rows: int
    rejects: int
    complete: bool


def run_status(run_dir: Path) -> RunStatus:
    """What a run folder holds, from its markers (cheap: no checksums), without Ray."""
    layout = RunLayout(Path(run_dir))
    run_id = recorded_run_id(layout.root)
    if run_id is None:
        raise MotionDataError(str(run_dir), "not a motionaug run folder (no config.resolved.json)")
    config = json.loads(layout.config.read_text(encoding="utf-8"))["config"]
    styles = [s["name"] for s in config["styles"]]
    plan = Plan.model_validate_json(layout.plan.read_text(encoding="utf-8")) if layout.plan.is_file() else None
    markers = [read_shard_marker(p) for p in sorted(layout.shards_dir.glob("style=*/_unit-*.done"))]
    markers = [m for m in markers if m is not None]
    total = sum(1 for u in plan.units for s in styles if u.styles.get(s)) if plan else 0
    return RunStatus(
        run_dir=layout.root, run_id=run_id, planned=plan is not None, clips=plan.n_clips if plan else 0,
        styles_done=sum(layout.artifact_marker(s).is_file() for s in styles), styles_total=len(styles),
        shards_done=len(markers), shards_total=total, rows=sum(m.rows for m in markers),
        rejects=(plan.rejects if plan else 0) + sum(m.rejects for m in markers), complete=layout.success.is_file(),
    )  # fmt: skip


def read_shard_marker(path: Path) -> ShardMarker | None:
    from augment.shards import read_marker

    return read_marker(path, ShardMarker)  # type: ignore[return-value]
