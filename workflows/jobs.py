"""Runs submitted to a Ray cluster through the Jobs API (the dashboard's HTTP server, ``http://HEAD:8265``).

A run's submission id is ``motionaug-<run id>``: the run id is a hash of what the run produces, so
submitting the same config twice is refused by name instead of computing the rows twice. The config is
validated here, its paths made absolute, and shipped as ``motionaug-run.json`` in a tiny runtime_env
``working_dir``; the entrypoint is ``motionaug run motionaug-run.json --address auto`` (the job's driver
joins the cluster it runs on). The code itself is not shipped: every node runs an image or environment with
motionaug installed (deploy/Dockerfile). Token authentication: the token goes in an ``Authorization: Bearer``
header (docs/scale-out.md).
"""

from __future__ import annotations

import asyncio
import json
import os
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from motionaug.schemas.errors import MotionConfigError, MotionDataError
from motionaug.schemas.run_config import RunConfig

if TYPE_CHECKING:
    from ray.job_submission import JobSubmissionClient

JOB_PREFIX = "motionaug-"
CONFIG_NAME = "motionaug-run.json"
TERMINAL = frozenset({"SUCCEEDED", "FAILED", "STOPPED"})


@dataclass(frozen=True)
class SubmittedJob:
    job_id: str
    run_id: str
    run_dir: Path
    dashboard_url: str
    entrypoint: str
    name: str = ""


@dataclass(frozen=True)
class JobState:
    job_id: str
    status: str
    message: str
    run_dir: Path | None
    entrypoint: str
    name: str = ""


def job_id_for(run_or_job: str) -> str:
    """Submission id of a run id (``run-<hash>``); any other job id is returned as it is."""
    return f"{JOB_PREFIX}{run_or_job}" if run_or_job.startswith("run-") else run_or_job


def dashboard_url(address: str) -> str:
    """``HEAD:8265`` or ``http://HEAD:8265/`` -> ``http://HEAD:8265`` (the Jobs API speaks HTTP)."""
    address = address.strip().rstrip("/")
    if not address:
        raise MotionConfigError("--address", "empty; give the dashboard URL, e.g. http://HEAD:8265")
    scheme = address.split("://", 1)[0].lower() if "://" in address else "http"
    if scheme not in ("http", "https"):
        hint = "a Ray Client address" if scheme == "ray" else f"a {scheme}:// address"
        reason = f"is {hint}; the Jobs API needs the cluster's dashboard URL, e.g. http://HEAD:8265"
        raise MotionConfigError(f"--address {address}", reason)
    url = address if "://" in address else f"http://{address}"
    from urllib.parse import urlsplit

    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError as err:
        raise MotionConfigError(f"--address {address}", f"not a URL ({err}); e.g. http://HEAD:8265") from None
    if not parts.hostname or (port is not None and not 0 < port < 65536):
        raise MotionConfigError(f"--address {address}", "not a URL with a host; e.g. http://HEAD:8265")
    return url


def auth_headers() -> dict[str, str]:
    """``Authorization: Bearer <token>`` from RAY_AUTH_TOKEN, RAY_AUTH_TOKEN_PATH or ~/.ray/auth_token.

    Ray 2.60's client only attaches the token when RAY_AUTH_MODE=token is set in the client's own
    environment; passing the header explicitly works either way and changes no process-wide state.
    ``RAY_AUTH_MODE=disabled`` sends nothing.
    """
    if os.environ.get("RAY_AUTH_MODE", "").lower() == "disabled":
        return {}
    token = os.environ.get("RAY_AUTH_TOKEN", "").strip()
    if not token:
        path = Path(os.environ.get("RAY_AUTH_TOKEN_PATH") or Path.home() / ".ray" / "auth_token").expanduser()
        token = path.read_text(encoding="utf-8").strip() if path.is_file() else ""
    return {"Authorization": f"Bearer {token}"} if token else {}


def connect(address: str) -> JobSubmissionClient:
    """A Jobs API client for the cluster whose dashboard is at ``address``, token attached."""
    from ray.job_submission import JobSubmissionClient

    url = dashboard_url(address)
    with _cluster_errors(url):
        try:
            return JobSubmissionClient(url, headers=auth_headers())
        except RuntimeError as err:  # a server that answers but is not a Ray dashboard (its version check fails)
            first = (str(err).splitlines() or [""])[0][:200]
            reason = f"not a Ray dashboard ({first}); give the cluster's dashboard URL, e.g. http://HEAD:8265"
            raise MotionDataError(url, reason) from None


@dataclass(frozen=True)
class ClusterNodes:
    """What a cluster's dashboard says of its capacity: each alive node's total resources, and whether an
    autoscaler runs (then a request no node meets now may still be met by a node it adds)."""

    nodes: list[dict[str, float]]
    autoscales: bool


def cluster_nodes(address: str, timeout_s: float = 30.0) -> ClusterNodes:
    """The alive nodes' resources from the state API (``/api/v0/nodes``) and the autoscaler's presence from
    ``/api/cluster_status``, read through the dashboard with the token attached."""
    from urllib.error import HTTPError, URLError
    from urllib.request import Request, urlopen

    url = dashboard_url(address)
    connect(address)  # the Jobs API's own lines for a cluster that is down or is not a Ray dashboard

    def get(path: str) -> dict[str, Any]:
        request = Request(f"{url}{path}", headers=auth_headers())
        try:
            with urlopen(request, timeout=timeout_s) as answer:  # noqa: S310 (an http(s) URL, checked above)
                return json.loads(answer.read().decode("utf-8"))
        except HTTPError as err:
            if err.code in (401, 403):
                raise MotionDataError(url, f"token refused (HTTP {err.code}); see docs/scale-out.md") from None
            raise MotionDataError(url, f"{path} answered HTTP {err.code}; is this a Ray dashboard?") from None
        except (URLError, OSError, ValueError) as err:
            reason = f"cannot reach the Ray dashboard ({type(err).__name__} reading {path}; is the cluster up?)"
            raise MotionDataError(url, reason) from None

    try:
        rows = get("/api/v0/nodes?limit=10000&detail=1")["data"]["result"]["result"]
        status = get("/api/cluster_status")["data"]
    except (KeyError, TypeError):
        raise MotionDataError(url, "the dashboard's node list has an unknown shape; is this a Ray dashboard?") from None
    nodes = [
        {k: float(v) for k, v in (row.get("resources_total") or {}).items()}
        for row in rows
        if row.get("state") == "ALIVE"
    ]
    return ClusterNodes(nodes=nodes, autoscales=not fixed_size(status))


def fixed_size(status: dict[str, Any]) -> bool:
    """Whether ``/api/cluster_status`` shows a cluster no autoscaler grows: no monitor report, or Ray's read-only
    node provider (``ray start`` nodes), which names each node's type after the node itself (``node_<id>``). Any
    other shape counts as autoscaling, so a request is never refused on a cluster that might grow."""
    if status.get("autoscalingStatus") is None:
        return True
    mapping = ((status.get("clusterStatus") or {}).get("autoscalerReport") or {}).get("nodeTypeMapping")
    return isinstance(mapping, dict) and bool(mapping) and all(v == f"node_{k}" for k, v in mapping.items())


@contextmanager
def _cluster_errors(url: str) -> Iterator[None]:
    """Connection, auth and HTTP failures of the Jobs API as one-line MotionDataErrors."""
    from ray.exceptions import AuthenticationError

    try:
        yield
    except AuthenticationError as err:
        first = str(err).splitlines()[0]
        raise MotionDataError(url, f"token refused ({first}); see docs/scale-out.md") from None
    except (ConnectionError, OSError) as err:  # requests' errors are OSErrors; ConnectionError: refused, reset
        detail = "" if isinstance(err, ConnectionError) else f" ({type(err).__name__})"
        reason = f"cannot reach the Ray dashboard{detail} (is the cluster up and the port right?)"
        raise MotionDataError(url, reason) from None


def _job_missing(err: RuntimeError) -> bool:
    text = str(err)
    return "404" in text or "does not exist" in text


RETRY_LOCK_WAIT_S = 120.0


def entrypoint(config_name: str = CONFIG_NAME, lock_wait_s: float = 0.0) -> str:
    """The command the job's driver runs on the cluster (``auto``: the cluster the job runs on). A retry waits
    ``lock_wait_s`` for the run folder: Ray reports a stopped job STOPPED while its driver may still be exiting."""
    import shlex

    wait = f" --lock-wait {lock_wait_s:g}" if lock_wait_s else ""
    return f"motionaug run {shlex.quote(config_name)} --address auto{wait}"


def shipped_config(config: RunConfig) -> dict[str, Any]:
    """The validated config as JSON, paths absolute, ``compute.address`` cleared (the job sets ``auto``)."""
    data = config.model_dump(mode="json")
    data["compute"]["address"] = None
    return data


def job_name(config: RunConfig, name: str | None = None, max_styles: int = 4) -> str:
    """What the dashboard's job list shows in its Name column: ``stats-synthetic: stats x 2 styles (proud, old)``."""
    styles = [s.name for s in config.styles]
    shown = ", ".join(styles[:max_styles]) + (f", +{len(styles) - max_styles} more" if len(styles) > max_styles else "")
    label = "style" if len(styles) == 1 else "styles"
    return f"{name or config.output.name}: {config.method.name} x {len(styles)} {label} ({shown})"


def job_metadata(config: RunConfig, name: str | None = None) -> dict[str, str]:
    """The job's metadata (strings only): ``job_name`` is the key Ray's dashboard shows as the job's name."""
    return {
        "job_name": job_name(config, name),
        "run_id": config.run_id(),
        "run_dir": str(config.output),
        "config": name or "",
        "method": config.method.name,
        "styles": ",".join(s.name for s in config.styles),
        "tool": "motionaug",
    }


def submit_run(
    config: RunConfig,
    address: str,
    retry: bool = False,
    runtime_env: dict[str, Any] | None = None,
    name: str | None = None,
) -> SubmittedJob:
    """Submit ``config`` as job ``motionaug-<run id>``; refuse (MotionDataError) if the run was submitted.

    ``retry`` resubmits a run whose every attempt FAILED or was STOPPED as ``motionaug-<run id>-<n>``
    (Ray never reuses a submission id); the new job resumes from the shards already on disk. ``name`` (the
    config file's name) leads the job name shown on the dashboard; the run folder's name stands in without it.
    """
    client = connect(address)
    url = dashboard_url(address)
    run_id = config.run_id()
    job_id = next_attempt(client, url, run_id, retry)
    command = entrypoint(lock_wait_s=RETRY_LOCK_WAIT_S if job_id != job_id_for(run_id) else 0.0)
    with tempfile.TemporaryDirectory(prefix="motionaug-submit-") as folder:
        (Path(folder) / CONFIG_NAME).write_text(json.dumps(shipped_config(config), indent=1), encoding="utf-8")
        env = {**(runtime_env or {}), "working_dir": folder}
        metadata = job_metadata(config, name)
        with _cluster_errors(url):
            try:
                client.submit_job(entrypoint=command, submission_id=job_id, runtime_env=env, metadata=metadata)
            except RuntimeError as err:
                if "already exists" in str(err):
                    raise MotionDataError(job_id, f"run {run_id} was already submitted as job {job_id}") from None
                raise MotionDataError(job_id, f"submission failed: {str(err).splitlines()[0]}") from None
    return SubmittedJob(
        job_id=job_id,
        run_id=run_id,
        run_dir=config.output,
        dashboard_url=url,
        entrypoint=command,
        name=metadata["job_name"],
    )


def next_attempt(client: JobSubmissionClient, url: str, run_id: str, retry: bool) -> str:
    """The submission id for this run: the base id, or with ``retry`` the next ``-<n>`` after failed attempts."""
    base = job_id_for(run_id)
    attempt, job_id = 1, base
    while (status := _job_status_or_none(client, url, job_id)) is not None:
        if not retry or status not in ("FAILED", "STOPPED"):
            hint = "; --retry resubmits it" if status in ("FAILED", "STOPPED") else ""
            reason = f"run {run_id} was already submitted as job {job_id} ({status}){hint}"
            raise MotionDataError(job_id, reason)
        attempt += 1
        job_id = f"{base}-{attempt}"
    return job_id


def _job_status_or_none(client: JobSubmissionClient, url: str, job_id: str) -> str | None:
    with _cluster_errors(url):
        try:
            return str(client.get_job_status(job_id))
        except RuntimeError as err:
            if _job_missing(err):
                return None
            raise MotionDataError(job_id, str(err).splitlines()[0]) from None


def _state(client: JobSubmissionClient, url: str, job: str) -> JobState:
    job_id = job_id_for(job)
    with _cluster_errors(url):
        try:
            info = client.get_job_info(job_id)
        except RuntimeError as err:
            if _job_missing(err):
                raise MotionDataError(job_id, f"no such job on {url}") from None
            raise MotionDataError(job_id, str(err).splitlines()[0]) from None
    run_dir = (info.metadata or {}).get("run_dir")
    return JobState(
        job_id=job_id,
        status=str(info.status),
        message=info.message or "",
        entrypoint=info.entrypoint or "",
        run_dir=Path(run_dir) if run_dir else None,
        name=(info.metadata or {}).get("job_name", ""),
    )


def job_state(address: str, job: str) -> JobState:
    """Status, message and run folder (from the job's metadata) of job or run id ``job``."""
    return _state(connect(address), dashboard_url(address), job)


def job_logs(address: str, job: str) -> str:
    """Everything the job's driver printed so far."""
    client, url = connect(address), dashboard_url(address)
    state = _state(client, url, job)  # one clear line for an unknown job
    with _cluster_errors(url):
        return client.get_job_logs(state.job_id)


def follow_logs(address: str, job: str, write: Callable[[str], None]) -> None:
    """Stream the job's log to ``write`` until the job ends (websocket tail of the Jobs API)."""
    client, url = connect(address), dashboard_url(address)
    state = _state(client, url, job)

    async def tail() -> None:
        async for chunk in client.tail_job_logs(state.job_id):
            write(chunk)

    with _cluster_errors(url):
        asyncio.run(tail())


def cancel_job(address: str, job: str) -> bool:
    """Ask the cluster to stop the job; False when it had already ended."""
    client, url = connect(address), dashboard_url(address)
    state = _state(client, url, job)
    if state.status in TERMINAL:
        return False
    with _cluster_errors(url):
        return bool(client.stop_job(state.job_id))


def wait_for_job(address: str, job: str, timeout: float = 600.0, poll: float = 0.5) -> JobState:
    """Poll until the job reaches SUCCEEDED/FAILED/STOPPED; MotionDataError after ``timeout`` seconds."""
    client, url = connect(address), dashboard_url(address)
    deadline = time.monotonic() + timeout
    while True:
        state = _state(client, url, job)
        if state.status in TERMINAL:
            return state
        if time.monotonic() > deadline:
            raise MotionDataError(state.job_id, f"still {state.status} after {timeout:.0f} s")
        time.sleep(poll)
