"""`motionaug demo` end to end on a small corpus, the default method: real Ray, real shards, and a rerun that
finishes at once (bench/bench_demo.py's ``check_demo``, which runs the other demo methods)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

from motionaug.workflows.demo import DEFAULT_METHOD

REPO = Path(__file__).resolve().parents[1]


def load_bench() -> ModuleType:
    spec = importlib.util.spec_from_file_location("bench_demo", REPO / "bench" / "bench_demo.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow
def test_the_default_demo_runs_end_to_end_and_resumes(tmp_path: Path) -> None:
    """The demo's own path (corpus, the network trained without the demo styles, each style learnt from its
    example, transfers, export, viewer), tiny size, with the default method (Style-ERD with its shapers)."""
    assert load_bench().check_demo(tmp_path, DEFAULT_METHOD) > 0
