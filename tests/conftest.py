"""Shared test fixtures: where the real third-party data lives, and how its absence is handled."""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path
from types import ModuleType

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
FIXTURES = Path(__file__).resolve().parent / "fixtures"


def require_shared(*parts: str) -> Path:
    """Path under ../shared/data; skip outside CI when absent, fail in CI (CI=true)."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        message = f"{path} is absent (the project's ../shared/data)"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(message)
        pytest.skip(message)
    return path


def load_bench(name: str) -> ModuleType:
    """``bench/NAME.py`` as a module, for a test that runs part of a bench (its cases or checks, one copy)."""
    spec = importlib.util.spec_from_file_location(name, REPO / "bench" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the class is made
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="session")
def shared_data() -> Path:
    return require_shared()


# Two styles with one example each, for workflow tests on a small synthetic corpus (ids of its first clips).
TWO_STYLES = [
    {
        "name": "proud",
        "words": {"adjective": "proud", "adverb": "proudly", "phrases": ["in a proud way"]},
        "examples": [{"source": "000004", "description": "a person walks proudly"}],
    },
    {
        "name": "old",
        "words": {"adjective": "old", "phrases": ["like an old person"]},
        "examples": [{"source": "000008", "description": "a person walks like an old person"}],
    },
]


@pytest.fixture(scope="module")
def ray_cluster():
    """A real local Ray with 2 CPUs for one test module; yields its GCS address. Only this module's Ray is stopped."""
    ray = pytest.importorskip("ray")
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    assert not ray.is_initialized()
    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray.get_runtime_context().gcs_address
    ray.shutdown()
