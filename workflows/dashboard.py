"""The Ray dashboard of an embedded run (``motionaug run --dashboard``): its URL, and keeping it up afterwards.

An embedded Ray lives as long as the command, so its dashboard (and the task list it shows) would die with the
run; ``--keep-dashboard`` holds the cluster after the run until Ctrl-C so a finished run's tasks can be viewed.
The dashboard binds 127.0.0.1 (Ray's default): it is reachable from this machine only (docs/ray.md).
"""

from __future__ import annotations

import signal
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from motionaug.schemas.run_config import ComputeConfig
from motionaug.workflows.ray_executor import ray_session


def dashboard_url(context: Any) -> str | None:
    """``http://127.0.0.1:8265`` from the RayContext ``ray.init`` returned; None without one or its dashboard."""
    address = context.dashboard_url if context is not None else None
    if not address:
        return None
    return address if "://" in address else f"http://{address}"


@contextmanager
def dashboard_session(compute: ComputeConfig) -> Iterator[str | None]:
    """Start the embedded Ray with its dashboard when the config asks for one; yields its URL (else None).

    A run by address uses its cluster's dashboard, so nothing starts here then; ``execute_run`` joins as usual.
    """
    if not compute.include_dashboard or compute.address:
        yield None
        return
    with ray_session(compute) as context:
        yield dashboard_url(context)


def hold_dashboard(url: str, say: Callable[[str], None], poll: float = 0.5) -> None:
    """Keep this process (and so the embedded Ray and its dashboard) alive until Ctrl-C or SIGTERM.

    The handlers are set here because a process started in the background by a shell inherits SIGINT ignored.
    """
    say(f"the run has ended; its tasks stay visible at {url} until Ctrl-C")
    previous = {sig: signal.signal(sig, _interrupt) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        while True:
            time.sleep(poll)
    except KeyboardInterrupt:
        say("stopping the dashboard")
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt
