"""Scheduling stages: the one place that decides what runs, in which order, and when a unit is complete.

The executor knows the stage contract (``workflows.pipeline.Stage``) and nothing else: it skips units whose
``done`` is verified, submits the rest to a backend with the result of the unit each depends on (a handle
when that unit is still running, so a transfer waits for its style's artefact without the driver in between),
writes each returned record as the unit's marker, and times every stage. Backends: ``LocalBackend`` runs in
this process (tests, laptops without Ray); ``workflows.ray_executor.RayBackend`` runs tasks on Ray.
"""

from __future__ import annotations

import time
from collections.abc import Hashable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

from motionaug.schemas.run_config import RunConfig
from motionaug.schemas.shards import Manifest, Plan, StageTiming
from motionaug.workflows.pipeline import (
    PlanStage,
    PrepareStage,
    Stage,
    TrainStage,
    TransferStage,
    build_manifest,
    empty_run,
    publish_record,
    trained_sha256,
)


class RunProgress(Protocol):
    """What the executor reports while it runs (the CLI draws bars from it)."""

    def stage(self, name: str, total: int, done: int = 0) -> None: ...

    def advance(self, name: str, n: int = 1) -> None: ...


class NullProgress:
    def stage(self, name: str, total: int, done: int = 0) -> None:
        pass

    def advance(self, name: str, n: int = 1) -> None:
        pass


class Backend(Protocol):
    """Where units run. ``submit`` returns a handle; ``wait`` returns the first finished one and its result."""

    def submit(self, stage: Stage, key: Hashable, dependency: Any) -> Any: ...

    def wait(self, handles: Sequence[Any]) -> tuple[Any, Any]: ...

    def abandon(self, handles: Sequence[Any]) -> None:
        """Stop what is still queued or running, after a unit failed or the driver was interrupted."""


def run_unit(stage: Stage, key: Hashable, dependency: Any) -> Any:
    """The body of every unit, wherever it runs: do it, then publish its record as the marker."""
    record = stage.run(key, dependency)
    publish_record(record, stage.marker_path(key))
    return record


class LocalBackend:
    """Runs each unit in this process when submitted (so a dependency's handle already holds its result)."""

    def submit(self, stage: Stage, key: Hashable, dependency: Any) -> Any:
        if isinstance(dependency, _Done):
            dependency = dependency.result
        return _Done(run_unit(stage, key, dependency))

    def wait(self, handles: Sequence[Any]) -> tuple[Any, Any]:
        return handles[0], handles[0].result

    def abandon(self, handles: Sequence[Any]) -> None:
        pass  # every unit already ran when it was submitted


@dataclass(frozen=True, eq=False)
class _Done:
    result: Any


@dataclass
class StageResults:
    """Per stage: each key's result, the keys that ran (not found done), and the timing."""

    results: dict[str, dict[Hashable, Any]] = field(default_factory=dict)
    ran: dict[str, list[Hashable]] = field(default_factory=dict)
    timings: dict[str, StageTiming] = field(default_factory=dict)


def run_stages(stages: Sequence[Stage], backend: Backend, progress: RunProgress) -> StageResults:
    """Run the stages' units, each after the unit it depends on; markers verified as done are skipped."""
    out = StageResults()
    start = time.perf_counter()
    pending: dict[Any, tuple[str, Hashable]] = {}
    ends: dict[str, float] = {}
    skipped: dict[str, int] = {}
    for stage in stages:
        keys = stage.keys()
        results = out.results.setdefault(stage.name, {})
        progress.stage(stage.name, len(keys))
        skipped[stage.name] = 0
        ends[stage.name] = start
        for key in keys:
            marker = stage.done(key)
            if marker is not None:
                results[key] = marker
                skipped[stage.name] += 1
                progress.advance(stage.name)
                continue
            dependency = stage.depends_on(key)
            value = out.results[dependency[0]][dependency[1]] if dependency else None
            handle = backend.submit(stage, key, value)
            results[key] = handle
            pending[handle] = (stage.name, key)
    try:
        while pending:
            handle, result = backend.wait(list(pending))
            name, key = pending.pop(handle)
            out.results[name][key] = result
            out.ran.setdefault(name, []).append(key)
            ends[name] = time.perf_counter()
            progress.advance(name)
    except BaseException:
        backend.abandon(list(pending))
        raise
    for stage in stages:
        seconds = ends[stage.name] - start
        out.timings[stage.name] = StageTiming(seconds=seconds, tasks=len(stage.keys()), skipped=skipped[stage.name])
    return out


@dataclass
class PipelineResult:
    manifest: Manifest
    transferred: int
    skipped: dict[str, int]


def run_pipeline(config: RunConfig, backend: Backend, progress: RunProgress | None = None) -> PipelineResult:
    """plan -> train (when the method trains) -> prepare + transfer -> manifest, on ``backend``."""
    from motionaug.augment.methods.registry import create_method

    progress = progress or NullProgress()
    method = create_method(config.method.name, config.method.params, config.hooks.modules)
    first = run_stages([PlanStage(config, method)], backend, progress)
    plan: Plan = first.results["plan"]["plan"]
    timings = dict(first.timings)
    trained = None
    if method.trains:
        train = run_stages([TrainStage(config, method)], backend, progress)
        trained = train.results["train"]["trained"]
        timings.update(train.timings)
    digest = trained_sha256(trained)  # what the style artefacts and shards record they were made from
    stages = [PrepareStage(config, plan, trained, digest), TransferStage(config, plan, trained, digest)]
    fan_out = run_stages(stages, backend, progress)
    timings.update(fan_out.timings)
    start = time.perf_counter()
    artifacts = {str(style): marker for style, marker in fan_out.results["prepare"].items()}
    shards = list(fan_out.results["transfer"].values())
    manifest = build_manifest(config, plan, artifacts, shards, timings, trained)
    from motionaug.augment.outputs.run_dir import RunDir

    if manifest.rows == 0 and plan.n_clips and not config.allow_empty:
        raise empty_run(RunDir(config.output), plan.n_clips)
    RunDir(config.output).write_manifest(manifest)
    timings["manifest"] = StageTiming(seconds=time.perf_counter() - start, tasks=1)
    manifest.stages = timings
    skipped = {name: timing.skipped for name, timing in fan_out.timings.items()}
    transferred = sum(fan_out.results["transfer"][key].rows for key in fan_out.ran.get("transfer", []))
    return PipelineResult(manifest=manifest, transferred=transferred, skipped=skipped)
