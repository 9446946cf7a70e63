"""Run progress as plain lines, for a stdout that is not a terminal (a Ray job's driver log, a pipe, a file).

Rich bars redraw in place, so off a terminal they reach the log only when the run ends; here each stage prints
one line at most every ``every`` seconds (and when it completes), with counts, rate and ETA, so
``motionaug logs --follow`` and the dashboard's log panel show the run as it goes.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field


@dataclass
class _Stage:
    total: int
    done: int
    started: float
    skipped: int
    last_print: float = field(default=float("-inf"))


def format_seconds(seconds: float) -> str:
    """``75`` -> ``1m15s``; ``3700`` -> ``1h01m``."""
    seconds = int(round(seconds))
    if seconds < 60:
        return f"{seconds}s"
    if seconds < 3600:
        return f"{seconds // 60}m{seconds % 60:02d}s"
    return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m"


class LineProgress:
    """The executor's ``RunProgress`` as log lines: ``transfer 120/590 tasks (20%), 3.1/s, ETA 2m31s``."""

    def __init__(
        self,
        every: float = 10.0,
        write: Callable[[str], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.every = every
        self.write = write or _print
        self.clock = clock
        self.stages: dict[str, _Stage] = {}

    def stage(self, name: str, total: int, done: int = 0) -> None:
        self.stages[name] = _Stage(total=total, done=done, started=self.clock(), skipped=done)
        if total == 0:
            return
        self.write(f"{name} 0/{total} tasks: started")

    def advance(self, name: str, n: int = 1) -> None:
        stage = self.stages[name]
        stage.done += n
        now = self.clock()
        if stage.done >= stage.total or now - stage.last_print >= self.every:
            stage.last_print = now
            self.write(self.line(name, stage, now))

    @staticmethod
    def line(name: str, stage: _Stage, now: float) -> str:
        """Counts, rate of the tasks run here (skipped ones excluded) and the time left at that rate."""
        elapsed = max(now - stage.started, 1e-9)
        ran = stage.done - stage.skipped
        rate = ran / elapsed
        head = f"{name} {stage.done}/{stage.total} tasks ({100 * stage.done // max(stage.total, 1)}%)"
        if stage.done >= stage.total:
            return f"{head}: done in {format_seconds(elapsed)}"
        eta = f"ETA {format_seconds((stage.total - stage.done) / rate)}" if rate > 0 else "ETA -"
        return f"{head}, {rate:.2f}/s, {eta}"


def _count(done: int, total: int) -> str:
    """``3/10``, or ``3`` when the total is not known (0)."""
    return f"{done}/{total}" if total else str(done)


def _print(line: str) -> None:
    print(line, file=sys.stdout, flush=True)


class Heartbeat:
    """A command's progress off a terminal: one line every ``every`` seconds from a background thread, whether or
    not the work reported since, so a job log never goes quiet; a line too when a stage starts and when it ends.
    A command that ends within its first ``every`` seconds prints nothing (a quick error stays one line).

    The work calls ``update(stage, done, total, metrics)`` (``augment.training.pretrain``'s progress hook has this
    signature): ``pretrain prior 120/4000 steps (3%), loss 0.1234, 2.31 steps/s, ETA 28m00s``.
    """

    def __init__(
        self,
        command: str,
        every: float = 10.0,
        unit: str = "steps",
        write: Callable[[str], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.command = command
        self.every = every
        self.unit = unit
        self.write = write or _print
        self.clock = clock
        self.started = clock()
        self.stage: str | None = None
        self.stage_started = self.started
        self.done = self.first = self.total = 0
        self.metrics: dict[str, float] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._spoke = False

    def _say(self, line: str) -> None:
        """Write ``line`` once the command has run ``every`` seconds; before that, stay quiet."""
        if not self._spoke and self.clock() - self.started < self.every:
            return
        self._spoke = True
        self.write(line)

    def update(self, stage: str, done: int, total: int, metrics: dict[str, float] | None = None) -> None:
        with self._lock:
            if stage != self.stage:
                if self.stage is not None and (not self.total or self.done < self.total):
                    self._say(self.line())  # the last state of a stage left early, or of one of unknown size
                self.stage, self.stage_started, self.first = stage, self.clock(), done
                self._say(f"{self.command} {stage} {_count(done, total)} {self.unit}: started")
            self.done, self.total, self.metrics = done, total, dict(metrics or {})
            if total and done >= total:
                self._say(self.line())

    def line(self) -> str:
        """The current state: stage, counts, the latest loss, rate and time left at that rate."""
        now = self.clock()
        if self.stage is None:
            return f"{self.command}: working, {format_seconds(now - self.started)} elapsed"
        elapsed = max(now - self.stage_started, 1e-9)
        head = f"{self.command} {self.stage} {_count(self.done, self.total)} {self.unit}"
        if self.total:
            head += f" ({100 * self.done // self.total}%)"
        loss = next((f", {k} {v:.4f}" for k, v in self.metrics.items() if "loss" in k), "")
        if self.total and self.done >= self.total:
            return f"{head}{loss}: done in {format_seconds(elapsed)}"
        rate = (self.done - self.first) / elapsed
        eta = f"ETA {format_seconds((self.total - self.done) / rate)}" if rate > 0 and self.total else "ETA -"
        return f"{head}{loss}, {rate:.2f} {self.unit}/s, {eta}, {format_seconds(now - self.started)} elapsed"

    def _beat(self) -> None:
        while not self._stop.wait(self.every):
            with self._lock:
                if self.stage is not None and self.total and self.done >= self.total:  # between stages
                    elapsed = format_seconds(self.clock() - self.started)
                    self._say(f"{self.command}: working (after {self.stage}), {elapsed} elapsed")
                else:
                    self._say(self.line())

    def __enter__(self) -> Heartbeat:
        self._thread = threading.Thread(target=self._beat, name=f"{self.command}-progress", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        if self._spoke:
            outcome = "failed" if exc[0] else "finished"
            self.write(f"{self.command}: {outcome} after {format_seconds(self.clock() - self.started)}")
