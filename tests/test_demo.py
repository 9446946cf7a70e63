"""`motionaug demo` end to end on a small corpus: real Ray, real shards, and a rerun that finishes at once."""

from __future__ import annotations

import os
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from motionaug.augment.corpus import HumanML3DReader

pytestmark = pytest.mark.slow


def test_demo_runs_end_to_end_and_resumes(tmp_path: Path) -> None:
    """The demo's own path (corpus, base-model pre-training, on-the-fly fine-tunes, transfers, export), tiny size."""
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    import ray

    from motionaug.workflows.demo import DEMO_STYLES, run_demo

    try:
        first = run_demo(tmp_path, clips=400, size="tiny")
        neutral = [c for c in HumanML3DReader(first.corpus) if c.style == "neutral" and 40 <= c.n_frames <= 199]
        rows = pq.read_table(tmp_path / "run" / "shards").num_rows
        assert rows == first.run.manifest.rows == len(neutral) * len(DEMO_STYLES)
        assert first.export.stylized > 0 and (tmp_path / "expanded" / "train.txt").is_file()
        assert set(pq.read_table(tmp_path / "run" / "shards", columns=["method"]).column("method").to_pylist()) == {
            "onthefly"
        }
        assert (tmp_path / "base_models" / "base.json").is_file()
        assert first.viewer.page == tmp_path / "run" / "viewer.html" and first.viewer.clips == rows
        second = run_demo(tmp_path, clips=400, size="tiny")
        assert second.run.transferred == 0 and second.run.manifest.rows == rows
        assert all(
            t.skipped == t.tasks for name, t in second.run.manifest.stages.items() if name in ("prepare", "transfer")
        )
    finally:
        if ray.is_initialized():
            ray.shutdown()
