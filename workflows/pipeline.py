"""The run's stages, datatrove-style: each a small class with one contract, and no idea where it runs.

A stage names its units of work (``keys``), the resources one needs, the unit of an earlier stage it waits for
(``depends_on``), whether a unit is done (``done``: its marker verified against the checksum it records) and how to
do one (``run``: returns the record published as the unit's marker). The executor schedules and owns completion and
never names a method or a stage. Stages: ``plan`` (units of clip ids, the content pool), ``train`` (once-per-run
models, when the method trains), ``prepare`` (one task per style), ``transfer`` (one task per unit x style) and
``manifest``. An artefact marker records the checksum of the models it was made from and a shard marker that of its
style's artefact, so a unit whose inputs changed is redone.
"""

from __future__ import annotations

import copy
import hashlib
import re
import resource
import subprocess
import time
import uuid
from abc import ABC, abstractmethod
from collections.abc import Hashable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel

from motionaug.augment.corpus import Corpus, MotionClip, Reject, write_rejects
from motionaug.augment.corpus.style_examples import load_style_examples
from motionaug.augment.methods.base import StyleModel, StyleTransferMethod, TrainingSpec, write_timings
from motionaug.augment.methods.hooks import output_shapers
from motionaug.augment.methods.registry import create_method, method_class
from motionaug.augment.methods.shaping import ShapedModel, read_shaping, write_shaping
from motionaug.augment.methods.shaping import pool_size as shaping_pool_size
from motionaug.augment.motion.travel import travels
from motionaug.augment.outputs.checksums import sha256_file, sha256_tree
from motionaug.augment.outputs.run_dir import RunDir
from motionaug.augment.outputs.shards import TransferOutput, output_row, publish_dir, write_shard
from motionaug.augment.training.pretrain import TRAINING_RECORDS
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.run_config import RunConfig
from motionaug.schemas.shards import ArtifactMarker, Manifest, Plan, PlanUnit, ShardMarker, StageTiming
from motionaug.schemas.styles import StyleSpec

CORPUS_REJECTS = "corpus.jsonl"


@dataclass(frozen=True)
class Resources:
    """What one task of a stage asks Ray for, and the config settings that ask it (named when it cannot fit)."""

    cpus: float = 1.0
    gpus: float = 0.0
    cpu_setting: str = ""
    gpu_setting: str = ""


def finetune_resources(config: RunConfig) -> Resources:
    c = config.compute
    return Resources(c.finetune_cpus, c.finetune_gpus, "compute.finetune_cpus", "compute.finetune_gpus")


def transfer_resources(config: RunConfig) -> Resources:
    c = config.compute
    return Resources(c.transfer_cpus, c.transfer_gpus, "compute.transfer_cpus", "compute.transfer_gpus")


def stage_resources(config: RunConfig, trains: bool) -> dict[str, Resources]:
    """Stage name -> what each of its tasks asks for (the plan stage's one CPU is within any of these)."""
    stages = {"train": finetune_resources(config)} if trains else {}
    return stages | {"prepare": finetune_resources(config), "transfer": transfer_resources(config)}


def derive_seed(*parts: object) -> int:
    """A stable 63-bit seed from any parts (``hash()`` is salted per process, so it cannot be used)."""
    digest = hashlib.sha256(":".join(str(p) for p in parts).encode()).digest()
    return int.from_bytes(digest[:8], "little") >> 1


def training_spec(config: RunConfig) -> TrainingSpec:
    return TrainingSpec(size=config.base_models.size, seed=config.seed)


def resolve_method_paths(config: RunConfig, base: Path) -> RunConfig:
    """The method's file params (its class's ``path_params``) made absolute against ``base``, as the generic
    paths are by ``resolve_paths``; an unknown method is left for ``check_config`` to name."""
    try:
        dotted_names = method_class(config.method.name).path_params
    except MotionDataError:
        return config
    params = copy.deepcopy(config.method.params)
    for dotted in dotted_names:
        *parents, leaf = dotted.split(".")
        level: Any = params
        for part in parents:
            level = level.get(part) if isinstance(level, dict) else None
        if isinstance(level, dict) and isinstance(level.get(leaf), str) and not Path(level[leaf]).is_absolute():
            level[leaf] = str((base / level[leaf]).resolve())
    return config.model_copy(update={"method": config.method.model_copy(update={"params": params})})


def training_corpus(config: RunConfig) -> Path:
    """The labelled corpus the method trains on: ``base_models.corpus``, else the run's corpus."""
    return config.base_models.corpus or config.corpus.path


def trained_dir(config: RunConfig) -> Path:
    """Where the method's once-per-run models are: ``base_models.path``, else ``<run>/base_models``."""
    return config.base_models.path or (config.output / "base_models")


def trained_sha256(trained: str | None) -> str | None:
    """Checksum of the once-per-run models (a folder or a file), None when the method has none."""
    if trained is None:
        return None
    path = Path(trained)
    return sha256_tree(path, TRAINING_RECORDS)[0] if path.is_dir() else sha256_file(path) if path.is_file() else None


def current_artifact(run_dir: RunDir, style: str, trained: str | None) -> ArtifactMarker | None:
    """The style's verified artefact marker when it was made from the once-per-run models of checksum
    ``trained`` (None: the method has none); None otherwise: the artefact is (re)made."""
    marker = run_dir.artifact(style)
    return marker if marker is not None and marker.trained_sha256 == trained else None


# ---- config checks -------------------------------------------------------------------------------


def check_config(config: RunConfig) -> StyleTransferMethod:
    """Everything checkable before Ray starts: corpus, example files, the method, its params and styles."""
    path = config.corpus.path
    if not path.exists():
        raise MotionDataError("config corpus.path", f"{path} not found")
    found = Corpus(path).format
    if config.corpus.format not in ("auto", found):
        raise MotionDataError("config corpus.format", f"{config.corpus.format!r} given, but {path} is {found}")
    for i, style in enumerate(config.styles):
        for j, example in enumerate(style.examples):
            source = Path(example.source)
            if source.suffix.lower() in (".npy", ".bvh") and not source.is_file():
                where = f"config styles[{i}].examples[{j}].source"
                raise MotionDataError(where, f"style example file {source} not found")
    method = create_method(config.method.name, config.method.params, config.hooks.modules)
    output_shapers.create_all(config.method.shapers, "config method.shapers")  # known names, valid options
    trained = None
    if method.trains:
        method.check_training(training_spec(config))
        trained = trained_dir(config) if method.is_trained(trained_dir(config)) else None
    for style in config.styles:
        method.check_style(style, trained, training_corpus(config))
    return method


# ---- corpus selection ------------------------------------------------------------------------------


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


def over_limit(clip: MotionClip, config: RunConfig) -> Reject | None:
    """A reject for a clip longer than the run's per-clip limit (``corpus.max_clip_frames``), else None."""
    limit = config.clip_frames()
    if clip.n_frames <= limit:
        return None
    reason = f"{clip.n_frames} frames, more than corpus.max_clip_frames={limit}; cut the clip or raise the limit"
    return Reject(id=clip.id, source=clip.source or str(config.corpus.path), reason=reason)


def commonest(rejects: Sequence[Reject]) -> str:
    """``most often: <reason> (<n> of <m>)`` over rejects (empty when there are none)."""
    if not rejects:
        return ""
    counts: dict[str, int] = {}
    for reject in rejects:
        counts[reject.reason] = counts.get(reject.reason, 0) + 1
    reason, n = max(counts.items(), key=lambda item: (item[1], item[0]))
    return f"most often: {reason[:160]} ({n} of {len(rejects)})"


def empty_selection(config: RunConfig, readable: int, rejects: Sequence[Reject]) -> MotionDataError:
    """The error of a plan that selects no clip: the filters matched none, or no clip of the corpus was readable."""
    hint = "; pass --allow-empty to run anyway"
    if readable:
        return MotionDataError("config corpus.filters", f"select 0 of the {readable} readable clips; loosen them{hint}")
    split = f" (split {config.corpus.split})" if config.corpus.split else ""
    why = f"; {commonest(rejects)}" if rejects else ""
    return MotionDataError("config corpus.path", f"{config.corpus.path}{split} has no readable clip{why}{hint}")


def empty_run(run_dir: RunDir, clips: int) -> MotionDataError:
    """The error of a run whose every transfer was rejected, with the commonest reason from its rejects files."""
    from motionaug.augment.corpus.rejects import read_rejects

    rejects = [r for path in sorted(run_dir.rejects_dir.glob("style=*/*.jsonl")) for r in read_rejects(path)]
    why = f"; {commonest(rejects)}" if rejects else ""
    reason = (
        f"run wrote 0 rows from {clips} clips{why}; see {run_dir.rejects_dir}, fix the config and rerun with --force"
        " (or pass --allow-empty)"
    )
    return MotionDataError(str(run_dir.root), reason)


def styles_for(clip_id: str, styles: Sequence[str], per_clip: str | int, seed: int) -> list[str]:
    """The styles a clip is stylized in: all, or ``per_clip`` of them drawn deterministically per clip."""
    if per_clip == "all":
        return list(styles)
    rng = np.random.default_rng(derive_seed("fan_out", seed, clip_id))
    chosen = set(rng.choice(len(styles), size=int(per_clip), replace=False).tolist())
    return [s for i, s in enumerate(styles) if i in chosen]


def load_examples(style: StyleSpec, config: RunConfig) -> list[MotionClip]:
    """The style's validated example clips (corpus ids are looked up in the run's corpus)."""
    corpus = Corpus(config.corpus.path)
    return load_style_examples(style, corpus.get)


def named_references(style: StyleSpec, config: RunConfig) -> list[MotionClip | None]:
    """Each example's ``reference`` clip from the run's corpus (None where the example names none)."""
    corpus = Corpus(config.corpus.path)
    found: list[MotionClip | None] = []
    for example in style.examples:
        clip = corpus.get(example.reference) if example.reference else None
        if example.reference and clip is None:
            raise MotionDataError(
                f"style {style.name!r} example {example.source!r}",
                f"reference {example.reference!r} is not in the corpus",
            )
        found.append(clip)
    return found


@dataclass
class Selection:
    """What the plan reads of the corpus in one pass: the chosen clips as (id, file, split), every readable id, the
    unreadable and the over-long clips, the chosen clips' frame counts and how many of them stay in place."""

    chosen: list[tuple[str, str, str | None]]
    all_ids: set[str]
    unreadable: list[Reject]
    too_long: list[Reject]
    frames: dict[str, int]
    in_place: int


def select_clips(config: RunConfig) -> Selection:
    """Stream the run's corpus split once through the clip limit and the filters (the plan stage and the dry run)."""
    corpus = Corpus(config.corpus.path, split=config.corpus.split)
    file_splits = corpus.file_splits()
    selection = Selection([], set(), [], [], {}, 0)
    for clip, file_key in corpus.with_files():
        selection.all_ids.add(clip.id)
        if (reject := over_limit(clip, config)) is not None:
            selection.too_long.append(reject)
        elif keep_clip(clip, config):
            selection.chosen.append((clip.id, file_key, Corpus.split_of(clip, file_splits)))
            selection.frames[clip.id] = clip.n_frames
            selection.in_place += not travels(clip.motion, clip.fps)
    selection.unreadable = corpus.rejects
    return selection


def example_coverage(config: RunConfig, plan: Plan) -> list[str]:
    """A line for each style none of whose examples moves as some of the run's clips do (travelling or in place:
    ``travel.travels``): those clips are transferred and shaped with an example of the other kind, which carries a
    style far less (docs/methods.md), so the user learns it from the run rather than from the outputs."""
    if plan.in_place is None:
        return []
    kinds = (
        (False, plan.in_place, "stay in place", "stays in place"),
        (True, plan.n_clips - plan.in_place, "travel", "travels"),
    )
    notes = []
    for style in config.styles:
        shown = {travels(e.motion, e.fps) for e in load_examples(style, config)}
        for travelling, n, do, does in kinds:
            if n and travelling not in shown:
                notes.append(
                    f"style {style.name!r}: {n:,} of the run's {plan.n_clips:,} clips {do} and none of its examples"
                    f" does; they take the change an example of another kind of motion shows, which carries the style"
                    f" far less: add an example that {does}, with its reference (docs/methods.md)"
                )
    return notes


# ---- the stage contract ---------------------------------------------------------------------------------


class Stage(ABC):
    """One kind of work: units named by ``keys``, each done by ``run`` on whatever worker the executor picks."""

    name: ClassVar[str]

    def __init__(self, config: RunConfig) -> None:
        self.config = config
        self.run_dir = RunDir(config.output)

    def resources(self) -> Resources:
        return Resources()

    @abstractmethod
    def keys(self) -> list[Hashable]:
        """The units of work, in the order they are submitted."""

    def task_name(self, key: Hashable) -> str:
        return f"{self.name}[{key}]"

    def depends_on(self, key: Hashable) -> tuple[str, Hashable] | None:
        """(stage, key) whose result ``run`` receives; None when the unit waits for nothing in its batch."""
        return None

    @abstractmethod
    def done(self, key: Hashable) -> Any | None:
        """The unit's verified result when it is complete already, else None (then it runs)."""

    @abstractmethod
    def run(self, key: Hashable, dependency: Any = None) -> Any:
        """Do one unit; returns its record (the executor writes it to ``marker_path`` when there is one)."""

    def marker_path(self, key: Hashable) -> Path | None:
        return None


class PlanStage(Stage):
    """Select clips (filters), split them into units of ``unit_size`` ids in a seeded order, choose the pool."""

    name = "plan"

    def __init__(self, config: RunConfig, method: StyleTransferMethod) -> None:
        super().__init__(config)
        self.pool_size = max(method.content_clips(), shaping_pool_size(config.method.shapers))

    def keys(self) -> list[Hashable]:
        return ["plan"]

    def task_name(self, key: Hashable) -> str:
        return "plan"

    def marker_path(self, key: Hashable) -> Path:
        return self.run_dir.plan_path

    def done(self, key: Hashable) -> Plan | None:
        plan = self.run_dir.read_plan()
        same = plan is not None and plan.run_id == self.config.run_id()
        return plan if same and plan.unit_size == self.config.compute.unit_size else None

    def run(self, key: Hashable, dependency: Any = None) -> Plan:
        selection = select_clips(self.config)
        self._check_example_ids(selection.all_ids)
        rejects = selection.unreadable + selection.too_long
        write_rejects(rejects, self.run_dir.rejects_dir / CORPUS_REJECTS)
        if not selection.chosen and not self.config.allow_empty:
            raise empty_selection(self.config, len(selection.all_ids) - len(selection.too_long), rejects)
        return self._units(selection, len(rejects))

    def _check_example_ids(self, all_ids: set[str]) -> None:
        """Example ids must name corpus clips; outside the run's split (an example from train) they are looked up."""
        whole = Corpus(self.config.corpus.path)
        for i, style in enumerate(self.config.styles):
            for j, example in enumerate(style.examples):
                if Path(example.source).suffix.lower() in (".npy", ".bvh") or example.source in all_ids:
                    continue
                if whole.get(example.source) is None:
                    where = f"config styles[{i}].examples[{j}].source"
                    reason = f"clip id {example.source!r} is not in the corpus (nor a .npy/.bvh file)"
                    raise MotionDataError(where, reason)

    def _pool(self, chosen: list[tuple[str, str, str | None]], order: np.ndarray) -> list[tuple[str, str, str | None]]:
        """The first ``pool_size`` clips of the seeded order, whatever the unit size (the units cut the same order,
        so at unit_size == pool_size the pool is unit 0); with ``corpus.pool_split``, of that split's clips."""
        split = self.config.corpus.pool_split
        if split is None or split == self.config.corpus.split:
            return sorted(chosen[int(i)] for i in order[: self.pool_size])
        corpus = Corpus(self.config.corpus.path, split=split)
        others = sorted((c.id, f, split) for c, f in corpus.with_files() if keep_clip(c, self.config))
        drawn = np.random.default_rng(derive_seed("pool", self.config.seed)).permutation(len(others))
        return sorted(others[int(i)] for i in drawn[: self.pool_size])

    def _units(self, selection: Selection, n_rejects: int) -> Plan:
        config = self.config
        chosen = sorted(selection.chosen)
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
        pool = self._pool(chosen, order)
        return Plan(
            run_id=config.run_id(),
            n_clips=len(chosen),
            unit_size=size,
            units=units,
            splits={m[0]: m[2] for m in chosen if m[2] is not None},
            rejects=n_rejects,
            pool=[m[0] for m in pool],
            pool_files=sorted({m[1] for m in pool}),
            in_place=selection.in_place,
        )


class TrainStage(Stage):
    """The method's once-per-run models: the user's own when ``base_models.path`` holds them, else trained."""

    name = "train"

    def __init__(self, config: RunConfig, method: StyleTransferMethod) -> None:
        super().__init__(config)
        self.method = method
        self.target = trained_dir(config)

    def resources(self) -> Resources:
        return finetune_resources(self.config)

    def keys(self) -> list[Hashable]:
        return ["trained"] if self.method.trains else []

    def task_name(self, key: Hashable) -> str:
        return self.name

    def done(self, key: Hashable) -> str | None:
        given = self.config.base_models.path is not None
        return str(self.target) if given and self.method.is_trained(self.target) else None

    def run(self, key: Hashable, dependency: Any = None) -> str:
        if not self.config.base_models.pretrain_if_missing:
            if not self.target.is_dir():
                reason = f"{self.target} not found and pretrain_if_missing is false"
                raise MotionDataError("config base_models.path", reason)
            return str(self.target)
        spec = training_spec(self.config)
        method = create_method(self.config.method.name, self.config.method.params, self.config.hooks.modules)
        return str(method.train(training_corpus(self.config), self.target, spec, progress=TrainLog()))


class TrainLog:
    """Training progress as a line per stage every 10% (Ray forwards a task's stdout to the driver)."""

    def __init__(self) -> None:
        self.started = time.perf_counter()
        self.last: dict[str, int] = {}

    def __call__(self, stage: str, step: int, total: int, metrics: dict[str, float]) -> None:
        tenth = min(10, step * 10 // max(total, 1))
        if tenth <= self.last.get(stage, 0) and step != 1:
            return
        self.last[stage] = tenth
        loss = f" loss {metrics['loss']:.4f}" if "loss" in metrics else ""
        print(f"training {stage}: {step}/{total}{loss} ({time.perf_counter() - self.started:.0f} s)", flush=True)


class PrepareStage(Stage):
    """One style: the method learns it from its examples (and the plan's pool); the artefact is published."""

    name = "prepare"

    def __init__(self, config: RunConfig, plan: Plan, trained: str | None, trained_hash: str | None = None) -> None:
        super().__init__(config)
        self.plan = plan
        self.trained = Path(trained) if trained else None
        self.trained_hash = trained_hash

    def resources(self) -> Resources:
        return finetune_resources(self.config)

    def keys(self) -> list[Hashable]:
        return [s.name for s in self.config.styles]

    def task_name(self, key: Hashable) -> str:
        return f"prepare[style={key}]"

    def marker_path(self, key: Hashable) -> Path:
        return self.run_dir.artifact_marker_path(str(key))

    def done(self, key: Hashable) -> ArtifactMarker | None:
        return current_artifact(self.run_dir, str(key), self.trained_hash)

    def run(self, key: Hashable, dependency: Any = None) -> ArtifactMarker:
        start = time.perf_counter()
        style_name = str(key)
        method = create_method(self.config.method.name, self.config.method.params, self.config.hooks.modules)
        shapers = self.config.method.shapers
        pool: list[MotionClip] = []
        if (method.content_clips() or shaping_pool_size(shapers)) and self.plan.pool:
            pool = Corpus(self.config.corpus.path).load(self.plan.pool, self.plan.pool_files)[0]
        style = next(s for s in self.config.styles if s.name == style_name)
        examples = load_examples(style, self.config)
        final = self.run_dir.artifact_dir(style_name)
        tmp = final.with_name(f".{style_name}.{uuid.uuid4().hex[:12]}.tmp")
        seed = derive_seed("finetune", self.config.seed, style_name)
        started = time.perf_counter()
        content = pool if method.content_clips() else []
        prepared = method.prepare(style, examples, self.trained, content, tmp, seed=seed)
        if shapers:  # beside the method's artefact, in its checksum: the examples and the shapers' references
            named = named_references(style, self.config) if any(e.reference for e in style.examples) else []
            write_shaping(tmp, style_name, examples, pool, shapers, named)
        write_timings(prepared, time.perf_counter() - started)
        returned = Path(prepared.folder)
        inner = returned.relative_to(tmp) if returned != tmp else Path()
        publish_dir(tmp, final)
        digest, files = sha256_tree(final)
        return ArtifactMarker(
            style=style_name,
            method=self.config.method.name,
            path=final.relative_to(self.run_dir.root).as_posix(),
            entry=inner.as_posix() if inner != Path() else "",
            sha256=digest,
            files=files,
            seconds=time.perf_counter() - start,
            trained_sha256=self.trained_hash,
        )


@dataclass(frozen=True, order=True)
class UnitKey:
    style: str
    unit: int

    def __str__(self) -> str:
        return f"style={self.style},unit={self.unit:04d}"


class TransferStage(Stage):
    """One (style, unit): load the style's artefact once, stylize the unit in batches, publish its shard."""

    name = "transfer"

    def __init__(self, config: RunConfig, plan: Plan, trained: str | None, trained_hash: str | None = None) -> None:
        super().__init__(config)
        self.plan = plan
        self.trained = Path(trained) if trained else None
        self.trained_hash = trained_hash
        self.units = {u.unit: u for u in plan.units}
        self._artifacts: dict[str, str | None] = {}  # style -> checksum of its current artefact (None: remade)

    def resources(self) -> Resources:
        return transfer_resources(self.config)

    def keys(self) -> list[Hashable]:
        return [UnitKey(s.name, u.unit) for s in self.config.styles for u in self.plan.units if u.styles.get(s.name)]

    def depends_on(self, key: Hashable) -> tuple[str, Hashable]:
        return ("prepare", key.style)  # type: ignore[attr-defined]

    def marker_path(self, key: Hashable) -> Path:
        return self.run_dir.shard_marker_path(key.style, key.unit)  # type: ignore[attr-defined]

    def done(self, key: Hashable) -> ShardMarker | None:
        """The verified marker when the shard was made with the style's current artefact and models."""
        style: str = key.style  # type: ignore[attr-defined]
        marker = self.run_dir.shard(style, key.unit)  # type: ignore[attr-defined]
        if marker is None:
            return None
        if style not in self._artifacts:
            artifact = current_artifact(self.run_dir, style, self.trained_hash)
            self._artifacts[style] = artifact.sha256 if artifact is not None else None
        same = marker.artifact_sha256 == self._artifacts[style] and marker.trained_sha256 == self.trained_hash
        return marker if same else None

    def run(self, key: Hashable, dependency: Any = None) -> ShardMarker:
        artifact: ArtifactMarker = dependency
        style, unit = key.style, self.units[key.unit]  # type: ignore[attr-defined]
        start = time.perf_counter()
        method = create_method(self.config.method.name, self.config.method.params, self.config.hooks.modules)
        model = method.load(self.run_dir.root / artifact.path / artifact.entry, self.trained)
        if self.config.method.shapers:
            shapers = output_shapers.create_all(self.config.method.shapers, "config method.shapers")
            model = ShapedModel(model, shapers, *read_shaping(self.run_dir.root / artifact.path))
        load_seconds = time.perf_counter() - start
        clips, rejects = Corpus(self.config.corpus.path).load(unit.styles[style], unit.files)
        splits = self.plan.splits
        context = {
            "run_id": self.config.run_id(),
            "method": self.config.method.name,
            "fps": 20.0,
            "artifact_ref": {"path": artifact.path, "sha256": artifact.sha256},
        }
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
        return self._publish(style, unit.unit, rows, rejects, start, load_seconds, artifact.sha256)

    def _publish(
        self,
        style: str,
        unit: int,
        rows: list[dict],
        rejects: list[Reject],
        start: float,
        load_seconds: float,
        artifact_sha256: str,
    ) -> ShardMarker:
        shard = self.run_dir.shard_path(style, unit)
        digest = write_shard(rows, shard)
        write_rejects(rejects, self.run_dir.rejects_path(style, unit))
        sums: dict[str, float] = {}
        counts: dict[str, int] = {}
        for row in rows:
            for name, value in row["scores"]:
                sums[name] = sums.get(name, 0.0) + value
                counts[name] = counts.get(name, 0) + 1
        return ShardMarker(
            style=style,
            unit=unit,
            path=shard.relative_to(self.run_dir.root).as_posix(),
            rows=len(rows),
            rejects=len(rejects),
            sha256=digest,
            artifact_sha256=artifact_sha256,
            trained_sha256=self.trained_hash,
            seconds=time.perf_counter() - start,
            load_seconds=load_seconds,
            peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            score_sums=sums,
            score_counts=counts,
        )


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
            ["git", "-C", str(repo), "describe", "--always", "--dirty", "--tags"],
            capture_output=True,
            text=True,
            timeout=5,
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


def build_manifest(
    config: RunConfig,
    plan: Plan,
    artifacts: dict[str, ArtifactMarker],
    shards: list[ShardMarker],
    stages: dict[str, StageTiming],
    trained: str | None,
) -> Manifest:
    """The per-unit markers merged into one record of the run."""
    shards = sorted(shards, key=lambda m: (m.style, m.unit))
    sums: dict[str, float] = {}
    counts: dict[str, int] = {}
    for marker in shards:
        for name, value in marker.score_sums.items():
            sums[name] = sums.get(name, 0.0) + value
            counts[name] = counts.get(name, 0) + marker.score_counts.get(name, 0)
    return Manifest(
        run_id=config.run_id(),
        config=config.model_dump(mode="json"),
        code_version=code_version(),
        method=config.method.name,
        artifacts=artifacts,
        shards=shards,
        rows=sum(m.rows for m in shards),
        rejects=plan.rejects + sum(m.rejects for m in shards),
        stages=stages,
        scores={k: sums[k] / counts[k] for k in sorted(sums) if counts.get(k)},
        base_models=trained,
    )


def write_resolved_config(config: RunConfig) -> None:
    RunDir(config.output).write_config(config.run_id(), config.model_dump(mode="json"))


def publish_record(record: BaseModel, path: Path | None) -> None:
    """The executor's half of completion: a unit's record written as its marker."""
    if path is not None:
        from motionaug.augment.outputs.run_dir import write_record

        write_record(record, path)


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
    run = RunDir(Path(run_dir))
    run_id = run.recorded_run_id()
    if run_id is None:
        raise MotionDataError(str(run_dir), "not a motionaug run folder (no config.resolved.json)")
    styles = run.styles()
    plan = run.read_plan()
    markers = run.shard_markers()
    total = sum(1 for u in plan.units for s in styles if u.styles.get(s)) if plan else 0
    return RunStatus(
        run_dir=run.root,
        run_id=run_id,
        planned=plan is not None,
        clips=plan.n_clips if plan else 0,
        styles_done=sum(run.artifact_marker_path(s).is_file() for s in styles),
        styles_total=len(styles),
        shards_done=len(markers),
        shards_total=total,
        rows=sum(m.rows for m in markers),
        rejects=(plan.rejects if plan else 0) + sum(m.rejects for m in markers),
        complete=run.success_path.is_file(),
    )
