"""`motionaug demo` end to end on a small corpus, the default method: real Ray, real shards, and a rerun that
finishes at once (bench/bench_demo.py's ``check_demo``, which runs the other demo methods)."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import load_bench

from motionaug.workflows.demo import DEFAULT_METHOD


@pytest.mark.slow
def test_the_default_demo_runs_end_to_end_and_resumes(tmp_path: Path) -> None:
    """The demo's own path (corpus, the network trained without the demo styles, each style learnt from its
    example, transfers, export, viewer), tiny size, with the default method (Style-ERD with its shapers)."""
    assert load_bench("bench_demo").check_demo(tmp_path, DEFAULT_METHOD) > 0
