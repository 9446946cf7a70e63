"""Run progress as plain lines, for a stdout that is not a terminal (a Ray job's driver log, a pipe, a file).

Rich bars redraw in place, so off a terminal they reach the log only when the run ends; here each stage prints
one line at most every ``every`` seconds (and when it completes), with counts, rate and ETA, so
``motionaug logs --follow`` and the dashboard's log panel show the run as it goes.
"""

from __future__ import annotations

import sys
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


def _print(line: str) -> None:
    print(line, file=sys.stdout, flush=True)
