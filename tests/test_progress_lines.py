"""Progress off a terminal: long commands whose stdout is a file or a pipe (a job log, ``nohup``, CI) print a line
at a fixed interval, with counts, the loss, the rate and an ETA, instead of bars that only draw on a terminal.

``pretrain`` runs as a real subprocess writing into a pipe; the gaps between its lines are measured.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import torch
from fixtures.evaluation.tiny_run import build_run, make_corpus
from typer.testing import CliRunner

from motionaug.workflows.cli import app
from motionaug.workflows.progress_log import Heartbeat

MOTIONAUG = Path(sys.executable).with_name("motionaug")
BVH = Path(__file__).resolve().parent / "fixtures" / "bvh" / "dataset-2"


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_heartbeat_lines_carry_counts_loss_rate_and_eta() -> None:
    lines: list[str] = []
    clock = Clock()
    beat = Heartbeat("pretrain", every=5.0, write=lines.append, clock=clock)
    assert beat.line() == "pretrain: working, 0s elapsed"
    beat.update("data", 0, 10, {})  # within the first interval: quiet
    clock.now = 5.0
    beat.update("prior", 0, 400, {})
    clock.now = 15.0
    beat.update("prior", 100, 400, {"loss": 0.5, "lr": 1e-4})
    assert beat.line() == "pretrain prior 100/400 steps (25%), loss 0.5000, 10.00 steps/s, ETA 30s, 15s elapsed"
    beat.update("prior", 400, 400, {"loss": 0.25})
    assert lines == [
        "pretrain data 0/10 steps (0%), 0.00 steps/s, ETA -, 5s elapsed",
        "pretrain prior 0/400 steps: started",
        "pretrain prior 400/400 steps (100%), loss 0.2500: done in 10s",
    ]


def test_heartbeat_prints_while_the_work_is_silent() -> None:
    lines: list[str] = []
    with Heartbeat("evaluate", every=0.05, write=lines.append):
        time.sleep(0.4)  # the work reports nothing meanwhile
    assert lines[-1].startswith("evaluate: finished after")
    assert sum("working" in line for line in lines) >= 3
    quick: list[str] = []
    with Heartbeat("evaluate", every=10.0, write=quick.append):
        pass
    assert quick == []  # a command done within one interval (a quick error) adds no line


@pytest.mark.slow
def test_pretrain_into_a_pipe_prints_a_line_at_least_every_interval(tmp_path: Path) -> None:
    runner = CliRunner()
    assert runner.invoke(app, ["corpus", "synth", "--out", str(tmp_path / "c"), "--clips", "24"]).exit_code == 0
    args = [str(MOTIONAUG), "pretrain", "--corpus", str(tmp_path / "c"), "--out", str(tmp_path / "base")]
    args += ["--size", "tiny", "--set", "prior_steps=60", "--set", "encoder_steps=10", "--set", "classifier_epochs=1"]
    env = os.environ | {"RAY_USAGE_STATS_ENABLED": "0", "HF_HUB_OFFLINE": "1", "TERM": "xterm"}
    proc = subprocess.Popen([*args, "--log-every", "1"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env)
    arrivals: list[tuple[float, str]] = []

    def read() -> None:
        for raw in proc.stdout:
            arrivals.append((time.monotonic(), raw.decode("utf-8", "replace").rstrip()))

    reader = threading.Thread(target=read)
    reader.start()
    assert proc.wait(timeout=300) == 0, "\n".join(line for _, line in arrivals)
    reader.join()
    progress = [(t, line) for t, line in arrivals if line.startswith("pretrain")]
    text = "\n".join(line for _, line in progress)
    assert "pretrain prior 60/60 steps (100%)" in text and "pretrain motion_encoder" in text
    assert any("loss" in line and "steps/s" in line and "ETA" in line for _, line in progress), text
    gaps = [b[0] - a[0] for a, b in zip(progress, progress[1:])]
    assert max(gaps) < 3.0, (gaps, text)  # --log-every 1; slack for a busy machine


@pytest.mark.parametrize("command", ["import-bvh", "evaluate", "export"])
def test_other_long_commands_print_progress_lines_off_a_terminal(
    command: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("MOTIONAUG_LOG_EVERY", "0.01")
    runner = CliRunner()  # its stdout is not a terminal
    if command == "import-bvh":
        result = runner.invoke(app, ["corpus", "import-bvh", str(BVH), "--out", str(tmp_path / "c")])
        assert result.exit_code == 0, result.output
        assert "import-bvh read 1/1 files" in result.output and "import-bvh: finished after" in result.output
        assert "no Mean/Std written" in result.output  # one take: by default a warning, not an error
    elif command == "export":
        torch.set_num_threads(1)
        run = build_run(make_corpus(tmp_path / "corpus", n_clips=10), tmp_path / "run", unit_size=4).output
        result = runner.invoke(app, ["export", str(run), "--out", str(tmp_path / "x")])
        assert result.exit_code == 0, result.output
        assert "export originals 10 clips" in result.output and "export stylized 20/20 clips (100%)" in result.output
    else:
        torch.set_num_threads(1)
        run = build_run(make_corpus(tmp_path / "corpus", n_clips=10), tmp_path / "run", unit_size=4).output
        result = runner.invoke(app, ["evaluate", str(run)])
        assert result.exit_code == 0, result.output
        assert "evaluate score 20/20 clips (100%)" in result.output and "evaluate: finished after" in result.output
        assert (run / "viewer.html").is_file() and "href='viewer.html'" in (run / "report.html").read_text("utf-8")
