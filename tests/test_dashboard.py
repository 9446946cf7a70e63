"""What a dashboard user sees of a run: progress lines in the driver's log while it runs, the embedded Ray's
dashboard kept up after the run (``--dashboard --keep-dashboard``), and its tasks named by stage and unit in
Ray's state API. A real local Ray (num_cpus=2) in a child ``motionaug run``; stopped by its own SIGINT."""

from __future__ import annotations

import copy
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml
from conftest import TWO_STYLES

from motionaug.schemas.run_config import load_run_config
from motionaug.workflows.jobs import job_metadata, job_name
from motionaug.workflows.progress_log import LineProgress, format_seconds

N_CLIPS = 40
UNIT_SIZE = 4


class FakeClock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_line_progress_prints_a_stage_at_most_every_n_seconds_with_rate_and_eta() -> None:
    clock, lines = FakeClock(), []
    progress = LineProgress(every=10.0, write=lines.append, clock=clock)
    progress.stage("transfer", 100)
    for _ in range(50):
        clock.now += 0.5
        progress.advance("transfer")
    assert lines[0] == "transfer 0/100 tasks: started"
    # the first advance prints, then one line per 10 s: at 0.5 s, 10.5 s and 20.5 s
    assert [line.split(" tasks")[0] for line in lines[1:]] == ["transfer 1/100", "transfer 21/100", "transfer 41/100"]
    assert lines[-1] == "transfer 41/100 tasks (41%), 2.00/s, ETA 30s"
    for _ in range(50):
        progress.advance("transfer")
    assert lines[-1] == "transfer 100/100 tasks (100%): done in 25s"
    assert format_seconds(75) == "1m15s" and format_seconds(3700) == "1h01m"


def test_an_empty_stage_prints_nothing() -> None:
    lines: list[str] = []
    LineProgress(write=lines.append).stage("train", 0)
    assert lines == []


def test_a_job_name_says_config_method_and_styles(tmp_path: Path) -> None:
    styles = [{**copy.deepcopy(TWO_STYLES[0]), "name": f"s{i}"} for i in range(6)]
    data = {"corpus": {"path": str(tmp_path)}, "styles": styles, "method": {"name": "stats"}, "output": "runs/x"}
    config = load_run_config(None, data=data)
    assert job_name(config, "big") == "big: stats x 6 styles (s0, s1, s2, s3, +2 more)"
    one = config.model_copy(update={"styles": config.styles[:1]})
    assert job_name(one) == "x: stats x 1 style (s0)"
    metadata = job_metadata(config, "big")
    assert metadata["job_name"] == job_name(config, "big") and metadata["run_id"] == config.run_id()
    assert all(isinstance(v, str) for v in metadata.values())  # the Jobs API takes strings only


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from motionaug.augment.synth import generate_corpus

    root = tmp_path_factory.mktemp("corpus") / "synth"
    generate_corpus(root, N_CLIPS, seed=0)
    return root


def _lines(stream, into: queue.Queue) -> None:
    for line in stream:
        into.put(line.rstrip("\n"))
    into.put(None)


def _read_until(lines: queue.Queue, seen: list[str], marker: str, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            line = lines.get(timeout=1.0)
        except queue.Empty:
            continue
        if line is None:
            raise AssertionError("motionaug run ended early:\n" + "\n".join(seen))
        seen.append(line)
        if marker in line:
            return
    raise AssertionError(f"no {marker!r} within {timeout:.0f} s:\n" + "\n".join(seen))


def task_names(url: str) -> list[str]:
    """Task names from ``ray.util.state.list_tasks`` against the dashboard, as a user's shell would ask (token mode
    set for that process only: Ray reads RAY_AUTH_MODE from the environment)."""
    code = (
        "import json, sys\n"
        "from ray.util.state import list_tasks\n"
        "tasks = list_tasks(address=sys.argv[1], limit=10000, raise_on_missing_output=False)\n"
        "print(json.dumps([t.name for t in tasks]))\n"
    )
    env = {**os.environ, "RAY_AUTH_MODE": "token", "RAY_USAGE_STATS_ENABLED": "0"}
    done = subprocess.run([sys.executable, "-c", code, url], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    import json

    return json.loads(done.stdout.strip().splitlines()[-1])


def test_a_run_streams_progress_keeps_its_dashboard_and_names_its_tasks(corpus: Path, tmp_path: Path) -> None:
    pytest.importorskip("ray")
    config = tmp_path / "run.yaml"
    data = {
        "corpus": {"path": str(corpus)},
        "styles": copy.deepcopy(TWO_STYLES),
        "method": {"name": "stats"},
        "compute": {"num_cpus": 2, "batch_size": 3, "unit_size": UNIT_SIZE},
        "output": str(tmp_path / "run"),
        "seed": 0,
    }
    config.write_text(yaml.safe_dump(data), encoding="utf-8")
    command = [sys.executable, "-m", "motionaug.workflows.cli", "run", str(config)]
    command += ["--dashboard", "--keep-dashboard", "--log-every", "0"]
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0"}
    child = subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, start_new_session=True
    )
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=_lines, args=(child.stdout, lines), daemon=True).start()
    seen: list[str] = []
    try:
        _read_until(lines, seen, "until Ctrl-C", timeout=300)
        url = next(m.group(1) for line in seen if (m := re.match(r"dashboard: (http://127\.0\.0\.1:\d+)", line)))
        # progress reached stdout (a pipe, as in a job's driver log) task by task, not only at the end
        counts = [int(m.group(1)) for line in seen if (m := re.match(r"transfer (\d+)/20 tasks", line))]
        assert counts == sorted(counts) and len(counts) >= 10 and counts[-1] == 20, seen
        assert any(re.fullmatch(r"transfer 20/20 tasks \(100%\): done in \S+", line) for line in seen), seen
        # the run has ended; its cluster and dashboard are still up, and the state API names every task
        names = task_names(url)
        assert "plan" in names
        assert sorted(n for n in names if n.startswith("prepare")) == ["prepare[style=old]", "prepare[style=proud]"]
        transfers = [n for n in names if n.startswith("transfer")]
        assert len(transfers) == 20 and len(set(transfers)) == 20
        assert all(re.fullmatch(r"transfer\[style=(proud|old),unit=\d{4}\]", n) for n in transfers), transfers
        child.send_signal(signal.SIGINT)
        assert child.wait(timeout=120) == 0
        _read_until(lines, seen, "stopping the dashboard", timeout=10)
    finally:
        if child.poll() is None:
            os.killpg(child.pid, signal.SIGKILL)
            child.wait()
