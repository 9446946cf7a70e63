"""Runs the pipeline on Ray: an embedded local cluster by default, or a cluster by address.

Each unit of a stage is one Ray task named after it (``prepare[style=proud]``,
``transfer[style=old,unit=0003]``); a transfer task receives its style's artefact marker as a Ray object
reference, so Ray starts it the moment that style is ready (no barrier, no driver callback). A task loads the
style artefact once and stylizes its whole unit in batches (the unit is the warm-model scope). Ray retries
tasks whose worker died (``max_retries``); an application error in one clip is a Reject, never a failed task.
Token authentication: see docs/ray.md.
"""

from __future__ import annotations

import logging
import os
import sys
import time
from collections.abc import Hashable, Iterator, Sequence
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from motionaug.augment.outputs.run_dir import RunDir
from motionaug.augment.outputs.run_lock import LOCK_FILE, RunLock
from motionaug.schemas.errors import MotionConfigError, MotionDataError
from motionaug.schemas.run_config import ComputeConfig, RunConfig, resolve_paths
from motionaug.schemas.shards import Manifest
from motionaug.workflows.executor import RunProgress, run_pipeline, run_unit
from motionaug.workflows.pipeline import (
    Resources,
    Stage,
    example_coverage,
    resolve_method_paths,
    write_resolved_config,
)
from motionaug.workflows.preflight import check_selection, plural, preflight, probe_address, unfit


@dataclass
class RunSummary:
    run_dir: Path
    run_id: str
    manifest: Manifest
    seconds: float
    transferred: int = 0
    skipped: dict[str, int] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def clips_per_second(self) -> float:
        transfer = self.manifest.stages.get("transfer")
        return self.transferred / transfer.seconds if transfer and transfer.seconds > 0 else 0.0


# ---- Ray session ---------------------------------------------------------------------------------


LOOPBACK = "127.0.0.1"
# Ray turns a loopback ``_node_ip_address`` into the host's routable address unless this is off; it reads it when
# ``ray`` is first imported (in this process) and in every process the embedded cluster starts.
LOOPBACK_SWITCH = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
LOG = logging.getLogger(__name__)


def ray_environment() -> None:
    """Process-wide Ray settings this product wants: no usage-stats upload."""
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")


@contextmanager
def loopback_only() -> Iterator[None]:
    """An embedded cluster on 127.0.0.1 only (node address, GCS, raylet, dashboard): nothing another machine
    can reach. Set around the import of ``ray`` and the start of the cluster, restored after."""
    before = os.environ.get(LOOPBACK_SWITCH)
    os.environ[LOOPBACK_SWITCH] = "0"
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(LOOPBACK_SWITCH, None)
        else:
            os.environ[LOOPBACK_SWITCH] = before


def is_loopback(address: str) -> bool:
    """Whether a cluster address names this machine's loopback (``127.0.0.1:6379``, ``localhost:6379``, ``ray://...``)."""
    host = address.rpartition("://")[2].split("/", 1)[0].rpartition(":")[0].strip("[]")
    return host in ("127.0.0.1", "localhost", "::1")


def _check_loopback() -> None:
    import ray

    address = ray.util.get_node_ip_address()
    if address != LOOPBACK:
        LOG.warning(
            "the embedded Ray listens on %s, not %s: ray was imported before motionaug started it", address, LOOPBACK
        )


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
    import motionaug.workflows.pipeline  # noqa: F401


def embedded_runtime_env() -> dict[str, Any]:
    """The runtime_env of an embedded cluster's job: warm workers (see ``warm_worker``)."""
    return {"worker_process_setup_hook": f"{__name__}.warm_worker"}


@contextmanager
def ray_session(compute: ComputeConfig) -> Iterator[Any]:
    """Use the Ray this process is already connected to, else start/join one and shut it down after.

    Embedded (``address`` None): ``ray.init(num_cpus=...)`` starts a private local cluster; with token
    auth on, Ray generates ``~/.ray/auth_token`` itself. With an address the token must already be there
    (``ray get-auth-token --generate`` before ``ray start --head``) or in ``RAY_AUTH_TOKEN``. The embedded
    cluster binds 127.0.0.1 only (``loopback_only``; docs/ray.md, Security).
    """
    loopback = compute.address is None or is_loopback(compute.address)
    if compute.address:
        client_auth_for_address()  # before Ray is imported: it reads RAY_AUTH_MODE then
    if loopback and "ray" not in sys.modules:
        with loopback_only():  # Ray reads the switch when it is first imported
            import ray
    import ray

    if ray.is_initialized():
        yield
        return
    ray_environment()
    options: dict[str, Any] = {"include_dashboard": compute.include_dashboard, "log_to_driver": True}
    if compute.address:
        try:
            with loopback_only() if loopback else nullcontext():  # 127.0.0.1 stays 127.0.0.1 (deploy/local-cluster.sh)
                context = ray.init(address=compute.address, **options)
        except (ConnectionError, RuntimeError, TimeoutError) as err:
            first = (str(err).splitlines() or [type(err).__name__])[0]
            raise MotionDataError(
                f"--address {compute.address}", f"cannot join the Ray cluster ({first[:200]})"
            ) from None
    else:
        with loopback_only():
            context = ray.init(  # address="local": never a stale "current cluster"
                address="local",
                num_cpus=compute.num_cpus,
                runtime_env=embedded_runtime_env(),
                _node_ip_address=LOOPBACK,
                dashboard_host=LOOPBACK,
                **options,
            )
        _check_loopback()
    try:
        yield context  # the RayContext (its dashboard_url); None above when Ray was already running
    finally:
        ray.shutdown()


def _assigned_threads() -> int:
    import ray

    cpus = ray.get_runtime_context().get_assigned_resources().get("CPU", 1.0)
    return max(1, int(cpus))


def ray_unit(stage: Stage, key: Hashable, dependency: Any) -> Any:
    """Body of every Ray task: size torch's thread pool to the CPUs Ray assigned, then run the unit."""
    import torch

    torch.set_num_threads(_assigned_threads())
    return run_unit(stage, key, dependency)


def node_resources() -> list[dict[str, float]]:
    """Total resources of each alive node of the cluster this process is connected to."""
    import ray

    return [dict(node.get("Resources", {})) for node in ray.nodes() if node.get("Alive")]


class RayBackend:
    """Each unit a named Ray task; a dependency still running is passed as its object reference.

    A task that asks for more than any node has would wait forever (Ray only logs an autoscaler message), so such
    tasks are watched: with ``unschedulable_s`` 0 (an embedded Ray: nothing can add a node) the first one stops the
    run at once, else when no node that fits has joined after ``unschedulable_s``; the error names the setting."""

    def __init__(self, retries: int, unschedulable_s: float = 0.0, poll_s: float = 5.0) -> None:
        import ray

        self.remote = ray.remote(ray_unit)
        self.retries = retries
        self.shared: dict[int, tuple[Stage, Any]] = {}
        self.waits_on: dict[Any, Any] = {}  # task -> the task result (object reference) it takes as input
        self.unschedulable_s = unschedulable_s
        self.poll_s = poll_s
        self.nodes = node_resources()
        self.unfit: dict[Any, tuple[str, Resources]] = {}  # task -> (stage, request) that no node can hold
        self.unfit_since: float | None = None

    def submit(self, stage: Stage, key: Hashable, dependency: Any) -> Any:
        import ray

        res = stage.resources()
        if unfit(res, self.nodes) is not None and self.unschedulable_s <= 0:
            raise unschedulable(stage.name, res, self.nodes, waited_s=None)
        options = {"name": stage.task_name(key), "num_cpus": res.cpus, "num_gpus": res.gpus}
        handle = self.remote.options(max_retries=self.retries, **options).remote(self._put(stage), key, dependency)
        if isinstance(dependency, ray.ObjectRef):
            self.waits_on[handle] = dependency
        if unfit(res, self.nodes) is not None:
            self.unfit[handle] = (stage.name, res)
            self.unfit_since = self.unfit_since or time.monotonic()
        return handle

    def _put(self, stage: Stage) -> Any:
        """The stage in the object store once, every task a reference to it: a stage carries the plan (1 MB at
        15,000 clips), and a copy per task made the driver's memory and the bytes sent grow with corpus x tasks."""
        import ray

        held = self.shared.get(id(stage))
        if held is None or held[0] is not stage:
            held = self.shared[id(stage)] = (stage, ray.put(stage))
        return held[1]

    def wait(self, handles: Sequence[Any]) -> tuple[Any, Any]:
        import ray

        while True:
            ready, _ = ray.wait(list(handles), num_returns=1, timeout=self.poll_s if self.unfit else None)
            if ready:
                self.unfit.pop(ready[0], None)
                return ready[0], _get(ready[0])
            self._check_schedulable(handles)

    def _check_schedulable(self, handles: Sequence[Any]) -> None:
        """Stop when tasks no node can hold have waited ``unschedulable_s`` and no node that fits has joined."""
        if self.unfit_since is None or time.monotonic() - self.unfit_since < self.unschedulable_s:
            return
        self.nodes = node_resources()
        waiting = set(handles)
        for handle, (stage, request) in list(self.unfit.items()):
            if handle not in waiting or unfit(request, self.nodes) is None:
                del self.unfit[handle]
                continue
            raise unschedulable(stage, request, self.nodes, waited_s=self.unschedulable_s)
        self.unfit_since = None

    def abandon(self, handles: Sequence[Any], grace_s: float = 20.0) -> None:
        """Cancel the run's other tasks and give them ``grace_s`` to end before the driver goes: a task that fails
        after its driver has gone makes Ray log an error on the driver's stderr, beside the run's one line.

        A finished task (the one that failed) is left alone, and so is a task whose input is another task's result
        that is not there yet or failed: it ends by itself once that input fails or is cancelled, and cancelling it
        races Ray's own completion of it (Ray 2.60's core worker then aborts the driver: "Tried to complete task
        that was not pending")."""
        import ray

        if not handles:
            return
        _, unfinished = ray.wait(list(handles), num_returns=len(handles), timeout=0)
        for handle in unfinished:
            dependency = self.waits_on.get(handle)
            if dependency is None or _succeeded(dependency):
                ray.cancel(handle)
        ray.wait(list(handles), num_returns=len(handles), timeout=grace_s)


def unschedulable(stage: str, request: Resources, nodes: list[dict[str, float]], waited_s: float | None) -> Exception:
    """The one line for a stage whose tasks ask for more than any node of the cluster has."""
    setting, amount, kind, most = unfit(request, nodes) or ("compute", 0.0, "?", 0.0)
    has = "none" if most == 0 else f"at most {most:g} per node"
    waited = f"; no node that has them joined in {waited_s:g} s" if waited_s else ""
    asks = f"{stage} tasks ask for {amount:g} {kind}{plural(amount)} each"
    reason = f"{asks}, but the cluster's nodes have {has}{waited}"
    return MotionConfigError(f"config {setting}", reason)


def _succeeded(ref: Any) -> bool:
    """Whether the task behind ``ref`` has finished without an error (a marker record: small to fetch)."""
    import ray

    try:
        ray.get(ref, timeout=0)
    except Exception:
        return False
    return True


def _get(ref: Any) -> Any:
    """``ray.get`` that re-raises a task's MotionDataError as itself (one line for the user)."""
    import ray

    try:
        return ray.get(ref)
    except ray.exceptions.RayTaskError as err:
        if isinstance(err.cause, MotionDataError):
            raise err.cause from None
        raise


# ---- run folder ----------------------------------------------------------------------------------


def prepare_run_dir(config: RunConfig, force: bool) -> None:
    """Start over (``force``), resume the same run, or refuse a folder that holds something else.

    Only with the folder's ``RunLock`` held by this process: then nothing it deletes (``force``, the sweep of
    temporaries) belongs to a live run.
    """
    root = config.output
    if not RunLock.is_held_here(root):
        raise RuntimeError(f"{root}: prepare_run_dir needs the run lock (with RunLock(root): ...)")
    run = RunDir(root)
    if any(path.name != LOCK_FILE for path in root.iterdir()):
        recorded = run.recorded_run_id()
        if recorded is None:
            raise MotionDataError(
                str(root), "output folder is not empty and is not a motionaug run; choose another --out"
            )
        if force or (recorded != config.run_id() and not holds_work(root)):
            run.clear()  # --force, or a run that failed before it made anything: not a claim on the folder
        elif recorded != config.run_id():
            reason = (
                f"holds run {recorded}, but this config is run {config.run_id()} (the config or the corpus changed);"
                " use --force or another --out"
            )
            raise MotionDataError(str(root), reason)
    run.success_path.unlink(missing_ok=True)
    run.sweep_temporaries()


NO_WORK = frozenset({LOCK_FILE, "config.resolved.json", "plan.json", "rejects"})


def holds_work(root: Path) -> bool:
    """Whether a run folder holds anything a run made (base models, style artefacts, shards, a manifest): a run
    that failed before (a config mistake found by a task) holds only its config, plan and rejects."""
    return any(path.name not in NO_WORK and not path.name.endswith(".tmp") for path in root.iterdir())


# ---- the run ---------------------------------------------------------------------------------------


def execute_run(
    config: RunConfig, force: bool = False, progress: RunProgress | None = None, lock_wait_s: float = 0.0
) -> RunSummary:
    """Run (or resume) the whole workflow for ``config`` as the one writer of its folder; returns the manifest
    and timings. Relative paths are made absolute against the working directory first, so what the run stores
    reads back from anywhere. ``lock_wait_s``: how long to wait for a folder's previous writer to exit."""
    config = resolve_method_paths(resolve_paths(config, Path.cwd()), Path.cwd())
    preflight(config)
    check_selection(config)
    compute = config.compute
    if compute.address is not None:
        probe_address(compute.address, compute.connect_timeout_s)
    with RunLock(config.output, wait_s=lock_wait_s):
        prepare_run_dir(config, force)
        write_resolved_config(config)
        start = time.perf_counter()
        with ray_session(compute):
            waits = compute.unschedulable_timeout_s if compute.address is not None else 0.0
            result = run_pipeline(config, RayBackend(compute.max_retries, unschedulable_s=waits), progress)
    plan = RunDir(config.output).read_plan()
    return RunSummary(
        run_dir=config.output,
        run_id=config.run_id(),
        manifest=result.manifest,
        seconds=time.perf_counter() - start,
        transferred=result.transferred,
        skipped=result.skipped,
        notes=example_coverage(config, plan) if plan is not None else [],
    )
