"""Runs the pipeline's stages on Ray: an embedded local cluster by default, or a cluster by address.

Fine-tunes are one task per style; the transfers of a style are submitted the moment ITS fine-tune
finishes (``ray.wait`` over all futures, no barrier), one task per (unit, style). A transfer task loads
the style artefact once and stylizes its whole unit in batches (the unit is the warm-model scope:
``bench/bench_workflow.py`` measures the load as a small fraction of a unit). Ray retries tasks whose
worker died (``max_retries``); an application error in one clip is a Reject, never a failed task.
Token authentication: see docs/ray.md.
"""

from __future__ import annotations

import os
import shutil
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from schemas.errors import MotionDataError
from augment.shards import sweep_temporaries
from schemas.run_config import ComputeConfig, RunConfig
from schemas.shards import ArtifactMarker, Manifest, Plan, PlanUnit, RunLayout, ShardMarker, StageTiming
from workflows.pipeline import (
    BaseModelsStage,
    FinetuneStage,
    ManifestStage,
    PlanStage,
    Resources,
    TransferStage,
    check_config,
    recorded_run_id,
    write_resolved_config,
)


class RunProgress(Protocol):
    """What the executor reports while it runs (the CLI draws bars from it)."""

    def stage(self, name: str, total: int, done: int = 0) -> None: ...

    def advance(self, name: str, n: int = 1) -> None: ...


@dataclass
class RunSummary:
    run_dir: Path
    run_id: str
    manifest: Manifest
    seconds: float
    transferred: int = 0
    skipped: dict[str, int] = field(default_factory=dict)

    @property
    def clips_per_second(self) -> float:
        transfer = self.manifest.stages.get("transfer")
        return self.transferred / transfer.seconds if transfer and transfer.seconds > 0 else 0.0


# ---- Ray session ---------------------------------------------------------------------------------


def ray_environment() -> None:
    """Process-wide Ray settings this product wants: no usage-stats upload."""
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")


def auth_token_available() -> bool:
    """Whether Ray would find a token: RAY_AUTH_TOKEN, RAY_AUTH_TOKEN_PATH or ~/.ray/auth_token."""
    if os.environ.get("RAY_AUTH_TOKEN"):
        return True
    path = os.environ.get("RAY_AUTH_TOKEN_PATH") or str(Path.home() / ".ray" / "auth_token")
    return Path(path).is_file()


def client_auth_for_address() -> None:
    """Send the token when joining a cluster by address.

    Ray 2.60 turns token auth on for clusters it starts locally (``ray.init()`` and ``ray start --head``),
    but a driver joining by address defaults to RAY_AUTH_MODE=disabled and is refused ("InvalidAuthToken").
    So when the user has not chosen a mode and a token is at hand, ask for token mode.
    """
    if "RAY_AUTH_MODE" not in os.environ and auth_token_available():
        os.environ["RAY_AUTH_MODE"] = "token"


def warm_worker() -> None:
    """Ray's ``worker_process_setup_hook``: import the stage code (torch, models) as a worker process starts.

    Without it a worker pays that import (seconds of CPU) when its first task arrives, inside the stage's wall
    time; with it, start-up overlaps planning and the driver's own work.
    """
    import workflows.pipeline  # noqa: F401


def embedded_runtime_env() -> dict[str, Any]:
    """The runtime_env of an embedded cluster's job: warm workers (see ``warm_worker``)."""
    return {"worker_process_setup_hook": f"{__name__}.warm_worker"}


@contextmanager
def ray_session(compute: ComputeConfig) -> Iterator[None]:
    """Use the Ray this process is already connected to, else start/join one and shut it down after.

    Embedded (``address`` None): ``ray.init(num_cpus=...)`` starts a private local cluster; with token
    auth on, Ray generates ``~/.ray/auth_token`` itself. With an address the token must already be there
    (``ray get-auth-token --generate`` before ``ray start --head``) or in ``RAY_AUTH_TOKEN``.
    """
    import ray

    if ray.is_initialized():
        yield
        return
    ray_environment()
    options: dict[str, Any] = {"include_dashboard": compute.include_dashboard, "log_to_driver": True}
    if compute.address:
        client_auth_for_address()
        ray.init(address=compute.address, **options)
    else:
        ray.init(  # address="local": never a stale "current cluster"
            address="local", num_cpus=compute.num_cpus, runtime_env=embedded_runtime_env(), **options
        )
    try:
        yield
    finally:
        ray.shutdown()


def _assigned_threads() -> int:
    import ray

    cpus = ray.get_runtime_context().get_assigned_resources().get("CPU", 1.0)
    return max(1, int(cpus))


def stage_call(stage: Any, method: str, *args: Any) -> Any:
    """Body of every Ray task: size torch's thread pool to the CPUs Ray assigned, then run the stage."""
    import torch

    torch.set_num_threads(_assigned_threads())
    return getattr(stage, method)(*args)


def _submit(remote: Any, name: str, res: Resources, retries: int, stage: Any, method: str, *args: Any) -> Any:
    options = {"name": name, "num_cpus": res.cpus, "num_gpus": res.gpus, "max_retries": retries}
    return remote.options(**options).remote(stage, method, *args)


def _get(ref: Any) -> Any:
    """``ray.get`` that re-raises a stage's MotionDataError as itself (one line for the user)."""
    import ray

    try:
        return ray.get(ref)
    except ray.exceptions.RayTaskError as err:
        if isinstance(err.cause, MotionDataError):
            raise err.cause from None
        raise


# ---- run folder ----------------------------------------------------------------------------------


def prepare_run_dir(config: RunConfig, force: bool) -> None:
    """Start over (``force``), resume the same run, or refuse a folder that holds something else."""
    root = config.output
    if root.exists() and any(root.iterdir()):
        recorded = recorded_run_id(root)
        if recorded is None:
            raise MotionDataError(str(root), "output folder is not empty and is not a motionaug run; choose another --out")
        if force:
            shutil.rmtree(root)
        elif recorded != config.run_id():
            reason = f"holds run {recorded}, but this config is run {config.run_id()}; use --force or another --out"
            raise MotionDataError(str(root), reason)
    root.mkdir(parents=True, exist_ok=True)
    RunLayout(root).success.unlink(missing_ok=True)
    sweep_temporaries(root)


# ---- the run ---------------------------------------------------------------------------------------


class _NullProgress:
    def stage(self, name: str, total: int, done: int = 0) -> None:
        pass

    def advance(self, name: str, n: int = 1) -> None:
        pass


def execute_run(config: RunConfig, force: bool = False, progress: RunProgress | None = None) -> RunSummary:
    """Run (or resume) the whole workflow for ``config``; returns the manifest and timings."""
    progress = progress or _NullProgress()
    check_config(config)
    prepare_run_dir(config, force)
    write_resolved_config(config)
    start = time.perf_counter()
    with ray_session(config.compute):
        import ray

        remote = ray.remote(stage_call)
        run = _Run(config, remote, progress)
        manifest = run.execute()
    return RunSummary(
        run_dir=config.output, run_id=config.run_id(), manifest=manifest, seconds=time.perf_counter() - start,
        transferred=run.transferred, skipped=run.skipped,
    )  # fmt: skip


class _Run:
    """The driver's bookkeeping for one execution: futures in flight and markers collected."""

    def __init__(self, config: RunConfig, remote: Any, progress: RunProgress) -> None:
        self.config = config
        self.remote = remote
        self.progress = progress
        self.retries = config.compute.max_retries
        self.stages: dict[str, StageTiming] = {}
        self.skipped: dict[str, int] = {"finetune": 0, "transfer": 0}
        self.transferred = 0

    def execute(self) -> Manifest:
        plan = self._plan()
        base_dir = self._base_models()
        finetune = FinetuneStage(self.config, base_dir)
        transfer = TransferStage(self.config, base_dir)
        artifacts, shards = self._fan_out(plan, finetune, transfer)
        start = time.perf_counter()
        manifest = ManifestStage(self.config).run(plan, artifacts, shards, self.stages, base_dir)
        self.stages["manifest"] = StageTiming(seconds=time.perf_counter() - start, tasks=1)
        return manifest

    def _plan(self) -> Plan:
        start = time.perf_counter()
        self.progress.stage("plan", 1)
        stage = PlanStage(self.config)
        plan = _get(_submit(self.remote, "plan", stage.resources(), self.retries, stage, "run"))
        self.progress.advance("plan")
        self.stages["plan"] = StageTiming(seconds=time.perf_counter() - start, tasks=1)
        return plan

    def _base_models(self) -> str | None:
        stage = BaseModelsStage(self.config)
        if not stage.needed():
            return None
        start = time.perf_counter()
        self.progress.stage("base_models", 1)
        base_dir = _get(_submit(self.remote, "base_models", stage.resources(), self.retries, stage, "run"))
        self.progress.advance("base_models")
        self.stages["base_models"] = StageTiming(seconds=time.perf_counter() - start, tasks=1)
        return base_dir

    def _fan_out(
        self, plan: Plan, finetune: FinetuneStage, transfer: TransferStage
    ) -> tuple[dict[str, ArtifactMarker], list[ShardMarker]]:
        import ray

        start = time.perf_counter()
        styles = [s.name for s in self.config.styles]
        work = {s: [u for u in plan.units if u.styles.get(s)] for s in styles}
        self.progress.stage("finetune", len(styles))
        self.progress.stage("transfer", sum(len(units) for units in work.values()))
        artifacts: dict[str, ArtifactMarker] = {}
        shards: list[ShardMarker] = []
        pending: dict[Any, tuple[str, str, int]] = {}
        sample = plan.units[0] if plan.units else None
        for style in styles:
            marker = finetune.done(style)
            if marker is not None:
                self.skipped["finetune"] += 1
                self._finetuned(style, marker, artifacts, work[style], plan, transfer, pending, shards)
                continue
            res = finetune.resources()
            ref = _submit(self.remote, finetune.task_name(style), res, self.retries, finetune, "run", style, sample)
            pending[ref] = ("finetune", style, -1)
        finetune_end = start
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            kind, style, unit = pending.pop(ready[0])
            result = _get(ready[0])
            if kind == "finetune":
                finetune_end = time.perf_counter()
                self._finetuned(style, result, artifacts, work[style], plan, transfer, pending, shards)
            else:
                shards.append(result)
                self.transferred += result.rows
                self.progress.advance("transfer")
        end = time.perf_counter()
        n_transfer = sum(len(units) for units in work.values())
        skipped = self.skipped
        self.stages["finetune"] = StageTiming(seconds=finetune_end - start, tasks=len(styles), skipped=skipped["finetune"])
        self.stages["transfer"] = StageTiming(seconds=end - start, tasks=n_transfer, skipped=skipped["transfer"])
        return artifacts, shards

    def _finetuned(
        self, style: str, marker: ArtifactMarker, artifacts: dict[str, ArtifactMarker], units: list[PlanUnit],
        plan: Plan, transfer: TransferStage, pending: dict[Any, tuple[str, str, int]], shards: list[ShardMarker],
    ) -> None:  # fmt: skip
        """A style's artefact is ready: submit its transfers (or collect the verified ones)."""
        artifacts[style] = marker
        self.progress.advance("finetune")
        for unit in units:
            done = transfer.done(style, unit.unit)
            if done is not None:
                shards.append(done)
                self.skipped["transfer"] += 1
                self.progress.advance("transfer")
                continue
            splits = {i: plan.splits[i] for i in unit.styles[style] if i in plan.splits}
            name = transfer.task_name(style, unit.unit)
            ref = _submit(self.remote, name, transfer.resources(), self.retries, transfer, "run", style, unit, splits, marker)
            pending[ref] = ("transfer", style, unit.unit)
