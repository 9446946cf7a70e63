"""Cluster operation on a real two-node Ray cluster on this machine (deploy/local-cluster.sh start 1).

Runs go through the Jobs API (``motionaug submit``), one worker process is SIGKILLed mid-run, and the
cluster is torn down by killing only the sessions the script started (never ``ray stop``). The corpus is
40 synthetic clips, two styles, the cheap ``stats`` method.
"""

from __future__ import annotations

import copy
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import pyarrow.parquet as pq
import pytest
import yaml
from conftest import TWO_STYLES
from typer.testing import CliRunner

from motionaug.schemas.run_config import load_run_config
from motionaug.workflows.cli import app

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[1]
DEPLOY = REPO / "deploy"
N_CLIPS = 40
UNIT_SIZE = 4
STYLES = TWO_STYLES
TOTAL_ROWS = N_CLIPS * len(STYLES)
TOTAL_SHARDS = N_CLIPS // UNIT_SIZE * len(STYLES)


def config_file(tmp: Path, corpus: Path, out: Path, seed: int) -> Path:
    data = {
        "corpus": {"path": str(corpus)},
        "styles": copy.deepcopy(STYLES),
        "method": {"name": "stats"},
        "compute": {"batch_size": 2, "unit_size": UNIT_SIZE, "max_retries": 3},
        "output": str(out),
        "seed": seed,
    }
    path = tmp / f"run-{seed}.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def cluster_env(state: Path) -> dict[str, str]:
    """Environment of local-cluster.sh: the venv's bin first (nodes and job drivers find `motionaug`)."""
    agent = free_port()
    while any(_taken(agent + i) for i in range(4)):
        agent = free_port()
    return {
        **os.environ,
        "PATH": f"{Path(sys.executable).parent}:{os.environ.get('PATH', '')}",
        "CLUSTER_DIR": str(state),
        "GCS_PORT": str(free_port()),
        "DASHBOARD_PORT": str(free_port()),
        "AGENT_PORT": str(agent),
        "CPUS_PER_NODE": "1",
        "RAY_USAGE_STATS_ENABLED": "0",
    }


def _taken(port: int) -> bool:
    with socket.socket() as sock:
        try:
            sock.bind(("127.0.0.1", port))
        except OSError:
            return True
    return False


@pytest.fixture(scope="module")
def cluster_dir() -> Iterator[Path]:
    """local-cluster.sh's state folder (its ``pids`` file names the nodes' sessions).

    Not under pytest's basetemp: a concurrent pytest session may prune it while Ray's sockets live there."""
    state = Path(tempfile.mkdtemp(prefix="motionaug-cluster-"))
    yield state
    shutil.rmtree(state, ignore_errors=True)


@pytest.fixture(scope="module")
def cluster(cluster_dir: Path) -> Iterator[str]:
    """Head + one worker node (1 CPU each); yields the dashboard URL; stops only these processes."""
    state = cluster_dir
    env = cluster_env(state)
    script = str(DEPLOY / "local-cluster.sh")
    try:
        started = subprocess.run([script, "start", "1"], env=env, capture_output=True, text=True, timeout=150)
        assert started.returncode == 0, started.stdout + started.stderr
        yield f"http://127.0.0.1:{env['DASHBOARD_PORT']}"
    finally:
        stopped = subprocess.run([script, "stop"], env=env, capture_output=True, text=True, timeout=60)
        assert stopped.returncode == 0, stopped.stderr
        left = subprocess.run([script, "status"], env=env, capture_output=True, text=True, timeout=30)
        assert "not running" in left.stdout


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from motionaug.augment.synth import generate_corpus

    root = tmp_path_factory.mktemp("corpus") / "synth"
    generate_corpus(root, N_CLIPS, seed=0)
    return root


def output_ids(run_dir: Path) -> list[str]:
    files = sorted((run_dir / "shards").glob("style=*/*.parquet"))
    return pq.read_table(files, columns=["output_id"])["output_id"].to_pylist() if files else []


def state_client(url: str):
    from ray.util.state.api import StateApiClient

    from motionaug.workflows.jobs import auth_headers

    return StateApiClient(address=url, headers={"Content-Type": "application/json", **auth_headers()})


def transfer_tasks(url: str, running_only: bool = False) -> list[dict]:
    """Transfer task attempts on the cluster, from the state API (name, state, worker_pid, node_id, attempt)."""
    from ray.util.state.common import ListApiOptions, StateResource

    filters = [("state", "=", "RUNNING")] if running_only else []
    options = ListApiOptions(filters=filters, detail=True, limit=10000)
    tasks = state_client(url).list(StateResource.TASKS, options, raise_on_missing_output=False)
    rows = [t if isinstance(t, dict) else t.__dict__ for t in tasks]
    return [r for r in rows if r["name"].startswith("transfer[")]


# ---- the tests -----------------------------------------------------------------------------------


@pytest.mark.filterwarnings("ignore:ssl=None is deprecated:DeprecationWarning")  # inside Ray's log tail
def test_submit_runs_on_two_nodes_and_a_second_submit_is_refused(cluster: str, corpus: Path, tmp_path: Path) -> None:
    from motionaug.workflows.jobs import wait_for_job

    out = tmp_path / "run"
    cfg = config_file(tmp_path, corpus, out, seed=0)
    job_id = f"motionaug-{load_run_config(cfg).run_id()}"
    submitted = CliRunner().invoke(app, ["submit", str(cfg), "--address", cluster])
    assert submitted.exit_code == 0, submitted.output
    assert job_id in submitted.output and f"{cluster}/#/jobs/{job_id}" in submitted.output
    again = CliRunner().invoke(app, ["submit", str(cfg), "--address", cluster])
    assert again.exit_code == 1 and "already submitted" in again.output and job_id in again.output
    state = wait_for_job(cluster, job_id, timeout=150)
    assert state.status == "SUCCEEDED", state.message
    ids = output_ids(out)
    assert len(ids) == TOTAL_ROWS == len(set(ids)) and (out / "_SUCCESS").is_file()

    status = CliRunner().invoke(app, ["status", job_id, "--address", cluster])
    assert status.exit_code == 0 and "SUCCEEDED" in status.output, status.output
    assert f"{TOTAL_SHARDS}/{TOTAL_SHARDS}" in status.output
    logs = CliRunner().invoke(app, ["logs", job_id, "--address", cluster])
    assert logs.exit_code == 0 and f"rows {TOTAL_ROWS}" in logs.output, logs.output[-2000:]
    assert "warning style 'old':" in logs.output  # its one example, a punch, stays in place; walks travel
    followed = CliRunner().invoke(app, ["logs", job_id, "--address", cluster, "--follow"])
    assert followed.exit_code == 0 and f"rows {TOTAL_ROWS}" in followed.output, followed.output[-2000:]
    after = CliRunner().invoke(app, ["submit", str(cfg), "--address", cluster, "--retry"])
    assert after.exit_code == 1 and "SUCCEEDED" in after.output


PROBE = """
import os
import ray
ray.init()

@ray.remote(num_cpus=1)
def where():
    import time
    time.sleep(1.0)
    return ray.get_runtime_context().get_node_id()

print("NODES", len(set(ray.get([where.remote(), where.remote()]))))
# a node unpacking this job's working_dir must not delete the one the driver runs in (a deleted cwd
# kills torch: "oneMKL FATAL ERROR: Cannot load libtorch_cpu.so")
print("CWD", "alive" if os.stat(".").st_nlink > 0 else "deleted")
"""


def test_a_job_uses_both_nodes(cluster: str, tmp_path: Path) -> None:
    """Two concurrent 1-CPU tasks on two 1-CPU nodes must land on different nodes."""
    from ray.util.state.common import ListApiOptions, StateResource

    from motionaug.workflows.jobs import connect, wait_for_job

    options = ListApiOptions(filters=[("state", "=", "ALIVE")])
    assert len(state_client(cluster).list(StateResource.NODES, options, raise_on_missing_output=False)) == 2
    (tmp_path / "probe.py").write_text(PROBE, encoding="utf-8")
    client = connect(cluster)
    job_id = client.submit_job(entrypoint="python probe.py", runtime_env={"working_dir": str(tmp_path)})
    assert wait_for_job(cluster, job_id, timeout=90).status == "SUCCEEDED"
    logs = client.get_job_logs(job_id)
    assert "NODES 2" in logs and "CWD alive" in logs, logs[-2000:]


def bundled_psutil():
    """The psutil Ray ships (``ray/thirdparty_files``), on the path once ``ray`` is imported."""
    import importlib

    import ray  # noqa: F401

    return importlib.import_module("psutil")


def cluster_listening(cluster_dir: Path) -> set[tuple[str, int]]:
    """(address, port) of every listening TCP socket of the processes local-cluster.sh started (their sessions)."""
    psutil = bundled_psutil()

    sessions = {int(line.split()[0]) for line in (cluster_dir / "pids").read_text().splitlines() if line.strip()}
    pids = set()
    for proc in psutil.process_iter(["pid"]):
        try:
            if os.getsid(proc.info["pid"]) in sessions:
                pids.add(proc.info["pid"])
        except (psutil.Error, ProcessLookupError):
            continue
    sockets = psutil.net_connections("inet")
    return {(c.laddr.ip, c.laddr.port) for c in sockets if c.status == "LISTEN" and c.pid in pids}


def test_the_local_cluster_listens_on_loopback_only(cluster: str, cluster_dir: Path) -> None:
    """Every port of every node (GCS, raylets, object managers, agents, dashboard) is on 127.0.0.1."""
    listening = cluster_listening(cluster_dir)
    ports = {port for _, port in listening}
    assert int(cluster.rsplit(":", 1)[1]) in ports and len(listening) >= 8, listening
    assert {ip for ip, _ in listening} <= {"127.0.0.1", "::ffff:127.0.0.1", "::1"}, listening


def busy_transfer_workers(cluster_dir: Path) -> list[int]:
    """Pids of this cluster's Ray workers running a transfer task now, read from the processes themselves.

    A worker's command line is ``ray::<task name>`` while it runs a task (``ray::IDLE`` after), and every process of
    a node stays in the session local-cluster.sh started it in, so no other cluster's worker is ever picked. The
    state API reports tasks about a second late: a short transfer task is often over before it is listed.
    """
    psutil = bundled_psutil()

    sessions = {int(line.split()[0]) for line in (cluster_dir / "pids").read_text().splitlines() if line.strip()}
    busy = []
    for proc in psutil.process_iter(["pid", "cmdline"]):
        try:
            title = " ".join(proc.info["cmdline"] or [])
            if title.startswith("ray::transfer[") and os.getsid(proc.info["pid"]) in sessions:
                busy.append(proc.info["pid"])
        except (psutil.Error, ProcessLookupError):
            continue
    return busy


def test_worker_sigkill_mid_run_loses_and_duplicates_nothing(
    cluster: str, cluster_dir: Path, corpus: Path, tmp_path: Path
) -> None:
    from motionaug.workflows.jobs import job_state, submit_run, wait_for_job

    out = tmp_path / "run"
    before = {(t["task_id"], t["attempt_number"]) for t in transfer_tasks(cluster)}
    job = submit_run(load_run_config(config_file(tmp_path, corpus, out, seed=1)), cluster)
    killed: list[int] = []
    deadline = time.monotonic() + 120
    polls = 0
    while time.monotonic() < deadline and len(killed) < 2:
        busy = [pid for pid in busy_transfer_workers(cluster_dir) if pid not in killed]
        if busy:
            os.kill(busy[0], signal.SIGKILL)  # a worker of this test's own cluster, mid-transfer
            killed.append(busy[0])
            time.sleep(0.5)
        polls += 1
        if polls % 100 == 0 and job_state(cluster, job.job_id).status not in ("PENDING", "RUNNING"):
            break
        time.sleep(0.005)
    assert killed, "no running transfer task was seen to kill"
    state = wait_for_job(cluster, job.job_id, timeout=150)
    assert state.status == "SUCCEEDED", state.message
    ids = output_ids(out)
    assert len(ids) == TOTAL_ROWS and len(set(ids)) == TOTAL_ROWS
    after = [t for t in transfer_tasks(cluster) if (t["task_id"], t["attempt_number"]) not in before]
    retried = [t for t in after if t["attempt_number"] >= 1]
    assert retried, f"killed workers {killed}, but no transfer task was retried"


def test_cancel_stops_a_run_and_retry_resumes_it(cluster: str, corpus: Path, tmp_path: Path) -> None:
    from motionaug.workflows.jobs import connect, wait_for_job

    out = tmp_path / "run"
    cfg = config_file(tmp_path, corpus, out, seed=2)
    job_id = f"motionaug-{load_run_config(cfg).run_id()}"
    assert CliRunner().invoke(app, ["submit", str(cfg), "--address", cluster]).exit_code == 0
    cancelled = CliRunner().invoke(app, ["cancel", job_id, "--address", cluster])
    assert cancelled.exit_code == 0 and "stop requested" in cancelled.output, cancelled.output
    assert wait_for_job(cluster, job_id, timeout=60).status == "STOPPED"
    refused = CliRunner().invoke(app, ["submit", str(cfg), "--address", cluster])
    assert refused.exit_code == 1 and "--retry" in refused.output
    retried = CliRunner().invoke(app, ["submit", str(cfg), "--address", cluster, "--retry"])
    assert retried.exit_code == 0 and f"{job_id}-2" in retried.output, retried.output
    # the stopped driver may still hold the run folder: the retry waits for it instead of failing
    assert "--lock-wait" in connect(cluster).get_job_info(f"{job_id}-2").entrypoint
    final = wait_for_job(cluster, f"{job_id}-2", timeout=150)
    assert final.status == "SUCCEEDED", connect(cluster).get_job_logs(f"{job_id}-2")[-3000:]
    assert sorted(output_ids(out)) == sorted(set(output_ids(out))) and len(output_ids(out)) == TOTAL_ROWS


def test_unknown_job_and_unreachable_cluster_are_one_line_errors(cluster: str) -> None:
    missing = CliRunner().invoke(app, ["status", "motionaug-run-000000000000", "--address", cluster])
    assert missing.exit_code == 1 and "no such job" in missing.output
    nowhere = CliRunner().invoke(app, ["logs", "x", "--address", f"http://127.0.0.1:{free_port()}"])
    assert nowhere.exit_code == 1 and "cannot reach" in nowhere.output
    lines = [line for line in nowhere.output.splitlines() if line.strip()]
    assert len(lines) == 1, nowhere.output


@pytest.mark.parametrize(
    ("setting", "named"),
    [("compute.transfer_cpus=4", "compute.transfer_cpus"), ("compute.transfer_gpus=1", "compute.transfer_gpus")],
)
def test_submit_refuses_what_no_node_of_the_cluster_has(
    cluster: str, corpus: Path, tmp_path: Path, setting: str, named: str
) -> None:
    """The cluster's nodes are read through its dashboard before submitting: exit 2, one line, no job, no folder."""
    from motionaug.workflows.jobs import cluster_nodes, connect

    capacity = cluster_nodes(cluster)
    assert not capacity.autoscales and sorted(n["CPU"] for n in capacity.nodes) == [1.0, 1.0]
    out = tmp_path / "run"
    cfg = config_file(tmp_path, corpus, out, seed=7)
    before = {job.submission_id for job in connect(cluster).list_jobs()}
    result = CliRunner().invoke(app, ["submit", str(cfg), "--address", cluster, "--set", setting])
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code == 2 and len(lines) == 1 and named in lines[0] and "cluster's nodes" in lines[0], lines
    assert {job.submission_id for job in connect(cluster).list_jobs()} == before and not out.exists()


def test_a_cluster_counts_as_fixed_only_when_its_monitor_says_so() -> None:
    from motionaug.workflows.jobs import fixed_size

    read_only = {"autoscalerReport": {"nodeTypeMapping": {"ab": "node_ab", "cd": "node_cd"}}}
    assert fixed_size({"autoscalingStatus": None})
    assert fixed_size({"autoscalingStatus": "up", "clusterStatus": read_only})
    grows = {"autoscalerReport": {"nodeTypeMapping": {"ab": "ray.head.default", "cd": "gpu-workers"}}}
    assert not fixed_size({"autoscalingStatus": "up", "clusterStatus": grows})
    assert not fixed_size({"autoscalingStatus": "up", "clusterStatus": {}})


def test_wrong_token_is_refused(cluster: str, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("RAY_AUTH_TOKEN", "0" * 32)
    result = CliRunner().invoke(app, ["status", "motionaug-run-000000000000", "--address", cluster])
    assert result.exit_code == 1 and "token refused" in result.output, result.output


def test_auth_headers_follow_ray_sources(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from motionaug.workflows.jobs import auth_headers, dashboard_url, job_id_for

    monkeypatch.delenv("RAY_AUTH_TOKEN", raising=False)
    monkeypatch.delenv("RAY_AUTH_MODE", raising=False)
    (tmp_path / "tok").write_text("abc\n")
    monkeypatch.setenv("RAY_AUTH_TOKEN_PATH", str(tmp_path / "tok"))
    assert auth_headers() == {"Authorization": "Bearer abc"}
    monkeypatch.setenv("RAY_AUTH_TOKEN", "xyz")
    assert auth_headers() == {"Authorization": "Bearer xyz"}
    monkeypatch.setenv("RAY_AUTH_MODE", "disabled")
    assert auth_headers() == {}
    assert dashboard_url("head:8265/") == "http://head:8265" and job_id_for("run-ab") == "motionaug-run-ab"
    assert job_id_for("motionaug-run-ab") == "motionaug-run-ab"


# ---- deploy/ files ---------------------------------------------------------------------------------


def load_yaml(name: str) -> dict:
    data = yaml.safe_load((DEPLOY / name).read_text(encoding="utf-8"))
    assert isinstance(data, dict), name
    return data


def containers(cluster_spec: dict) -> list[dict]:
    groups = [cluster_spec["headGroupSpec"], *cluster_spec["workerGroupSpecs"]]
    return [c for g in groups for c in g["template"]["spec"]["containers"]]


def test_kuberay_rayjob_runs_motionaug_with_token_auth() -> None:
    job = load_yaml("kuberay-rayjob.yaml")
    assert (job["apiVersion"], job["kind"]) == ("ray.io/v1", "RayJob")
    assert job["spec"]["entrypoint"].startswith("motionaug run ") and "--address auto" in job["spec"]["entrypoint"]
    cluster = job["spec"]["rayClusterSpec"]
    assert cluster["rayVersion"] == "2.60.0" and cluster["authOptions"]["mode"] == "token"
    assert all(c["image"].startswith("ghcr.io/example/motionaug:") for c in containers(cluster))


def test_kuberay_raycluster_has_cpu_and_gpu_groups() -> None:
    cluster = load_yaml("kuberay-raycluster.yaml")
    assert (cluster["apiVersion"], cluster["kind"]) == ("ray.io/v1", "RayCluster")
    spec = cluster["spec"]
    assert spec["rayVersion"] == "2.60.0" and spec["authOptions"]["mode"] == "token"
    gpu = {g["groupName"]: g for g in spec["workerGroupSpecs"]}["gpu"]
    limits = gpu["template"]["spec"]["containers"][0]["resources"]["limits"]
    assert limits["nvidia.com/gpu"] == "1" and gpu["template"]["spec"]["containers"][0]["image"].endswith(":cuda")


def test_ray_up_config_has_a_gpu_worker_group_and_token_mode() -> None:
    config = load_yaml("ray-cluster.yaml")
    types = config["available_node_types"]
    assert config["head_node_type"] in types and "gpu_worker" in types
    assert types["gpu_worker"]["docker"]["worker_image"].endswith(":cuda")
    starts = config["head_start_ray_commands"] + config["worker_start_ray_commands"]
    assert all("RAY_AUTH_MODE=token" in cmd for cmd in starts if "ray start" in cmd)
    assert "/home/ray/.ray/auth_token" in config["file_mounts"]


def test_dockerfiles_pin_torch_through_constraints() -> None:
    cpu = (DEPLOY / "Dockerfile").read_text(encoding="utf-8")
    cuda = (DEPLOY / "Dockerfile.cuda").read_text(encoding="utf-8")
    assert "FROM python:3.11-slim" in cpu and "FROM python:3.11-slim" in cuda
    for text in (cpu, cuda):
        installs = [line for line in text.splitlines() if "pip install" in line and not line.startswith("#")]
        assert installs and all("-c constraints.txt" in line for line in installs)
    assert "whl/cpu" in cpu and "torch==2.13.0" in cpu and "torch==2.13.0+${CUDA_TAG}" in cuda
    assert "torch==2.13.0" in (REPO / "constraints.txt").read_text(encoding="utf-8")


def test_local_cluster_script_never_runs_a_bare_ray_stop() -> None:
    text = (DEPLOY / "local-cluster.sh").read_text(encoding="utf-8")
    code = [line.split("#")[0] for line in text.splitlines()]
    assert not any("ray stop" in line or '"$RAY_BIN" stop' in line for line in code)
    assert subprocess.run(["bash", "-n", str(DEPLOY / "local-cluster.sh")]).returncode == 0
    usage = subprocess.run([str(DEPLOY / "local-cluster.sh"), "bogus"], capture_output=True, text=True)
    assert usage.returncode == 1 and "usage" in usage.stderr
