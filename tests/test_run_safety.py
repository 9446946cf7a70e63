"""Run-folder safety: stored paths read back from anywhere, one writer per folder, provenance, format versions,
fsync on publishing, and an embedded Ray that listens on 127.0.0.1 only.

Real processes hold and lose the lock (SIGKILL); runs use a real local Ray (num_cpus=2) and the ``stats`` method.
"""

from __future__ import annotations

import copy
import json
import os
import shutil
import signal
import socket
import stat
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest
import yaml
from conftest import TWO_STYLES
from typer.testing import CliRunner

from motionaug.augment.outputs.checksums import sha256_tree
from motionaug.augment.outputs.run_dir import RunDir, write_record
from motionaug.augment.outputs.run_lock import LOCK_FILE, RunLock
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.run_config import RunConfig, load_run_config
from motionaug.schemas.shards import ShardMarker

N_CLIPS = 16
UNIT_SIZE = 4
PYTHON = sys.executable


def config_dict(corpus: Path | str, output: Path | str) -> dict:
    return {
        "corpus": {"path": str(corpus)},
        "styles": copy.deepcopy(TWO_STYLES),
        "method": {"name": "stats"},
        "compute": {"num_cpus": 2, "batch_size": 3, "unit_size": UNIT_SIZE},
        "output": str(output),
        "seed": 0,
    }


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from motionaug.augment.synth import generate_corpus

    root = tmp_path_factory.mktemp("corpus") / "synth"
    generate_corpus(root, N_CLIPS, seed=0)
    return root


def hold_lock(root: Path) -> subprocess.Popen:
    """Another process that takes the run lock and sleeps; returns once it holds it."""
    code = "import sys, time; from motionaug.augment.outputs.run_lock import RunLock\n"
    code += "RunLock(sys.argv[1]).acquire(); print('held', flush=True); time.sleep(120)"
    proc = subprocess.Popen([PYTHON, "-c", code, str(root)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "held"
    return proc


def kill_9(proc: subprocess.Popen) -> None:
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)


# ---- item 4: one writer per run folder ---------------------------------------------------------------


def test_a_second_taker_is_refused_naming_the_holder(tmp_path: Path) -> None:
    root = tmp_path / "run"
    holder = hold_lock(root)
    try:
        with pytest.raises(MotionDataError) as refused:
            RunLock(root).acquire()
        message = str(refused.value)
        assert "\n" not in message and f"pid {holder.pid} on {socket.gethostname()} since " in message
        assert message.startswith(str(root.resolve()))
    finally:
        kill_9(holder)


def test_the_lock_of_a_killed_run_is_taken_over_with_a_warning(tmp_path: Path, caplog) -> None:
    root = tmp_path / "run"
    holder = hold_lock(root)
    kill_9(holder)
    assert (root / LOCK_FILE).is_file()  # SIGKILL left the file; its flock died with the process
    with caplog.at_level("WARNING"), RunLock(root) as lock:
        assert lock.takeover is not None and f"pid {holder.pid}" in lock.takeover
        assert json.loads((root / LOCK_FILE).read_text())["pid"] == os.getpid()
        assert RunLock.is_held_here(root)
    assert f"pid {holder.pid}" in caplog.text and "took over" in caplog.text
    assert not (root / LOCK_FILE).exists() and not RunLock.is_held_here(root)


def test_a_waiting_taker_gets_the_lock_once_an_exiting_holder_is_gone(tmp_path: Path) -> None:
    """A retried job waits for the stopped job's driver, which Ray may report STOPPED before it has exited."""
    root = tmp_path / "run"
    holder = hold_lock(root)
    try:
        start = time.monotonic()
        with pytest.raises(MotionDataError, match="another motionaug run holds this folder"):
            RunLock(root, wait_s=0.5).acquire()
        assert time.monotonic() - start >= 0.5  # it did wait before refusing
        threading.Timer(0.5, kill_9, args=(holder,)).start()
        with RunLock(root, wait_s=30) as lock:
            assert lock.takeover is not None and f"pid {holder.pid}" in lock.takeover
    finally:
        if holder.poll() is None:
            kill_9(holder)


def test_the_lock_is_released_when_the_run_fails(tmp_path: Path) -> None:
    with pytest.raises(ZeroDivisionError), RunLock(tmp_path):
        _ = 1 / 0
    assert not (tmp_path / LOCK_FILE).exists()
    with RunLock(tmp_path) as lock:
        assert lock.takeover is None  # a clean release leaves nothing to take over


def test_cli_run_and_force_refuse_a_folder_a_live_run_holds(corpus: Path, tmp_path: Path) -> None:
    from motionaug.workflows.cli import app

    out = tmp_path / "run"
    config = tmp_path / "run.yaml"
    config.write_text(yaml.safe_dump(config_dict(corpus, out)), encoding="utf-8")
    holder = hold_lock(out)
    try:
        live_tmp = out / "shards" / "style=proud" / ".unit-00000.parquet.1.abc.tmp"  # the live run's temporary
        live_tmp.parent.mkdir(parents=True)
        live_tmp.write_text("half")
        for extra in ([], ["--force"]):
            result = CliRunner().invoke(app, ["run", str(config), "--out", str(out), *extra])
            assert result.exit_code == 1, result.output
            lines = [line for line in result.output.splitlines() if line.strip()]
            assert len(lines) == 1 and f"pid {holder.pid}" in lines[0], result.output
            assert "Traceback" not in result.output
            assert live_tmp.read_text() == "half"  # neither the sweep nor --force touched the live run's files
    finally:
        kill_9(holder)


def test_prepare_run_dir_needs_the_lock(corpus: Path, tmp_path: Path) -> None:
    from motionaug.workflows.ray_executor import prepare_run_dir

    (tmp_path / "run").mkdir()
    with pytest.raises(RuntimeError, match="needs the run lock"):
        prepare_run_dir(load_run_config(None, data=config_dict(corpus, tmp_path / "run")), force=False)


# ---- items 3, 4, 6: runs end to end ------------------------------------------------------------------


@pytest.fixture(scope="module")
def relative_run(ray_cluster: str, corpus: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A run started with a relative corpus path and a relative output, over a stale lock of a killed run."""
    from motionaug.workflows.ray_executor import execute_run

    start = tmp_path_factory.mktemp("cwd")
    holder = hold_lock(start / "runs" / "rel")
    kill_9(holder)
    before = Path.cwd()
    os.chdir(start)
    try:
        config = RunConfig.model_validate(config_dict(os.path.relpath(corpus, start), "runs/rel"))
        summary = execute_run(config)
    finally:
        os.chdir(before)
    assert summary.manifest.rows == N_CLIPS * len(TWO_STYLES)
    return start / "runs" / "rel"


def test_what_a_run_stores_reads_back_from_any_working_directory(
    relative_run: Path, corpus: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from motionaug.augment.outputs.export import export_run

    monkeypatch.chdir(tmp_path)  # not where the run was started
    run = RunDir(relative_run)
    stored = run.config()
    assert Path(stored["corpus"]["path"]) == corpus.resolve() and Path(stored["output"]) == relative_run.resolve()
    manifest = run.manifest()
    assert Path(manifest.config["corpus"]["path"]).is_absolute()
    summary = export_run(relative_run, tmp_path / "expanded")
    assert summary.stylized > 0 and summary.originals == N_CLIPS


def test_the_run_released_its_lock_after_taking_over(relative_run: Path) -> None:
    assert not (relative_run / LOCK_FILE).exists()


def test_shard_markers_record_the_artefact_they_were_made_with(relative_run: Path) -> None:
    manifest = RunDir(relative_run).manifest()
    for shard in manifest.shards:
        assert shard.artifact_sha256 == manifest.artifacts[shard.style].sha256 and shard.trained_sha256 is None


def test_a_remade_artefact_remakes_its_shards_only(ray_cluster: str, relative_run: Path, tmp_path: Path) -> None:
    from motionaug.workflows.ray_executor import execute_run

    out = tmp_path / "run"
    shutil.copytree(relative_run, out)
    run = RunDir(out)
    config = RunConfig.model_validate({**run.config(), "output": str(out)})
    # the style "proud" re-made into a different artefact: a verified marker with another checksum
    marker = run.artifact("proud")
    assert marker is not None
    (out / marker.path / "note.txt").write_text("re-made")
    digest, files = sha256_tree(out / marker.path)
    write_record(marker.model_copy(update={"sha256": digest, "files": files}), run.artifact_marker_path("proud"))
    before = {(m.style, m.unit): m.sha256 for m in run.shard_markers()}
    summary = execute_run(config)
    n_units = N_CLIPS // UNIT_SIZE
    assert summary.skipped["prepare"] == 2 and summary.skipped["transfer"] == n_units  # the "old" shards stay
    assert summary.transferred == N_CLIPS  # every "proud" clip was stylized again
    after = {(m.style, m.unit): m for m in run.shard_markers()}
    assert {m.artifact_sha256 for key, m in after.items() if key[0] == "proud"} == {digest}
    assert all(m.sha256 == before[key] for key, m in after.items() if key[0] == "old")
    assert all(m.sha256 != before[key] for key, m in after.items() if key[0] == "proud")  # rows name the new one


def test_a_corpus_rewritten_in_place_is_a_new_run(tmp_path: Path) -> None:
    from motionaug.augment.synth import generate_corpus
    from motionaug.workflows.pipeline import write_resolved_config
    from motionaug.workflows.ray_executor import prepare_run_dir

    root = tmp_path / "corpus"
    generate_corpus(root, 10, seed=0)
    first = load_run_config(None, data=config_dict(root, tmp_path / "run"))
    assert first.run_id() == load_run_config(None, data=config_dict(root, tmp_path / "run")).run_id()
    write_resolved_config(first)
    (tmp_path / "run" / "styles").mkdir()  # the first run made something: a folder of nothing would be taken over
    shutil.rmtree(root)
    generate_corpus(root, 10, seed=0)  # same path, same ids, rewritten
    again = load_run_config(None, data=config_dict(root, tmp_path / "run"))
    assert again.run_id() != first.run_id()
    with RunLock(tmp_path / "run"), pytest.raises(MotionDataError, match="the corpus changed"):
        prepare_run_dir(again, force=False)


def test_the_fingerprint_reads_the_humanml3d_content_folders() -> None:
    from motionaug.augment.corpus.humanml3d import MOTION_DIR, TEXT_DIR
    from motionaug.schemas.run_config import CORPUS_CONTENT_DIRS

    assert CORPUS_CONTENT_DIRS == (MOTION_DIR, TEXT_DIR)


# ---- item 6: format versions -------------------------------------------------------------------------


def _rewrite_version(path: Path, version: int) -> None:
    data = json.loads(path.read_text())
    path.write_text(json.dumps({**data, "version": version}))


def test_records_of_another_format_version_are_refused(relative_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    shutil.copytree(relative_run, out)
    run = RunDir(out)
    shard = run.shard_markers()[0]
    checks = [
        (run.manifest_path, run.manifest),
        (run.artifact_marker_path("proud"), lambda: run.artifact("proud")),
        (run.shard_marker_path(shard.style, shard.unit), lambda: run.shard(shard.style, shard.unit)),
    ]
    for path, read in checks:
        _rewrite_version(path, 2)
        with pytest.raises(MotionDataError) as refused:
            read()
        assert str(refused.value).startswith(f"{path}: format version 2, this motionaug reads 1")
        _rewrite_version(path, 1)
        assert read() is not None
    marker = run.shard_marker_path(shard.style, shard.unit)
    marker.write_text('{"vers')  # a torn or corrupt marker is no refusal: the unit is redone
    assert run.shard(shard.style, shard.unit) is None


# ---- item 7: fsync on publishing ---------------------------------------------------------------------


def test_publishing_fsyncs_files_and_their_folders(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from motionaug.augment.outputs.shards import publish_dir, write_shard

    synced: list[tuple[str, bool]] = []
    real_fsync = os.fsync

    def recording_fsync(fd: int) -> None:
        info = os.fstat(fd)
        synced.append((os.readlink(f"/proc/self/fd/{fd}"), stat.S_ISDIR(info.st_mode)))
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", recording_fsync)
    marker = ShardMarker(style="s", unit=0, path="x", rows=0, rejects=0, sha256="0", seconds=0.0)
    write_record(marker, tmp_path / "m" / "_unit-00000.done")
    write_shard([], tmp_path / "shards" / "unit-00000.parquet")
    staged = tmp_path / "styles" / ".proud.tmp"
    (staged / "sub").mkdir(parents=True)
    (staged / "sub" / "w.bin").write_bytes(b"w")
    publish_dir(staged, tmp_path / "styles" / "proud")
    files = {Path(p).name for p, is_dir in synced if not is_dir}
    folders = {Path(p) for p, is_dir in synced if is_dir}
    assert "w.bin" in files and any(name.startswith("._unit-00000.done") for name in files)
    assert any(name.startswith(".unit-00000.parquet") for name in files)
    assert {tmp_path / "m", tmp_path / "shards", tmp_path / "styles"} <= folders


# ---- item 11: the embedded Ray listens on 127.0.0.1 only ---------------------------------------------


def test_the_embedded_ray_binds_loopback_only(tmp_path: Path) -> None:
    code = textwrap.dedent(
        """
        import json
        from motionaug.schemas.run_config import ComputeConfig
        from motionaug.workflows.ray_executor import ray_session

        with ray_session(ComputeConfig(num_cpus=1)):  # as `motionaug run` does: ray not imported before
            import psutil  # Ray's own copy (ray puts its third-party folder on sys.path)
            import ray

            nodes = [n["NodeManagerAddress"] for n in ray.nodes()]
            gcs = ray.get_runtime_context().gcs_address
            tree = {p.pid for p in psutil.Process().children(recursive=True)} | {psutil.Process().pid}
            listening = sorted(
                {c.laddr.ip for c in psutil.net_connections("inet") if c.status == "LISTEN" and c.pid in tree}
            )
        print(json.dumps({"nodes": nodes, "gcs": gcs, "listening": listening}))
        """
    )
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0"}
    env.pop("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", None)
    done = subprocess.run([PYTHON, "-c", code], capture_output=True, text=True, timeout=300, cwd=tmp_path, env=env)
    assert done.returncode == 0, done.stderr[-3000:]
    facts = json.loads(done.stdout.strip().splitlines()[-1])
    assert facts["nodes"] == ["127.0.0.1"] and facts["gcs"].startswith("127.0.0.1:")
    assert facts["listening"] and set(facts["listening"]) <= {"127.0.0.1", "::ffff:127.0.0.1", "::1"}, facts


def test_deploy_manifests_keep_the_dashboard_off_public_interfaces() -> None:
    deploy = Path(__file__).resolve().parents[1] / "deploy"
    ray_up = yaml.safe_load((deploy / "ray-cluster.yaml").read_text(encoding="utf-8"))
    heads = [cmd for cmd in ray_up["head_start_ray_commands"] if "ray start" in cmd]
    assert heads and all("--dashboard-host=127.0.0.1" in cmd for cmd in heads)
    cluster = yaml.safe_load((deploy / "kuberay-raycluster.yaml").read_text(encoding="utf-8"))["spec"]
    job = yaml.safe_load((deploy / "kuberay-rayjob.yaml").read_text(encoding="utf-8"))["spec"]["rayClusterSpec"]
    assert cluster["headGroupSpec"]["serviceType"] == job["headGroupSpec"]["serviceType"] == "ClusterIP"
    local = (deploy / "local-cluster.sh").read_text(encoding="utf-8")
    assert "--node-ip-address 127.0.0.1" in local and "--dashboard-host 127.0.0.1" in local
    assert "ray_start_loopback.py" in local and (deploy / "ray_start_loopback.py").is_file()
