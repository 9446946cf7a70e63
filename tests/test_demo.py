"""`motionaug demo` end to end on a small corpus: real Ray, real shards, and a rerun that finishes at once."""

from __future__ import annotations

import os
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from motionaug.augment.corpus import HumanML3DReader
from motionaug.augment.training.evaluators import read_evaluators_info

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("method", ["erd", "onthefly"])
def test_demo_runs_end_to_end_and_resumes(tmp_path: Path, method: str) -> None:
    """The demo's own path (corpus, the network trained without the demo styles, each style learnt from its
    example, transfers, export), tiny size: the default (Style-ERD with its shapers) and on-the-fly."""
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    import ray

    from motionaug.workflows.demo import DEFAULT_METHOD, DEMO_STYLES, method_folder, run_demo

    run = method_folder(tmp_path, "run", method)
    try:
        first = run_demo(tmp_path, clips=400, size="tiny", method=method)
        neutral = [c for c in HumanML3DReader(first.corpus) if c.style == "neutral" and 40 <= c.n_frames <= 199]
        rows = pq.read_table(run / "shards").num_rows
        assert rows == first.run.manifest.rows == len(neutral) * len(DEMO_STYLES)
        assert first.run.notes == []  # a walk and a wave per style: every clip has an example of its kind
        assert first.export.stylized > 0 and (method_folder(tmp_path, "expanded", method) / "train.txt").is_file()
        assert set(pq.read_table(run / "shards", columns=["method"]).column("method").to_pylist()) == {method}
        trained_on = {c.style for c in HumanML3DReader(tmp_path / "corpus-without-demo-styles")}
        assert trained_on and not trained_on & set(DEMO_STYLES)  # every demo style is new to the network
        assert any(method_folder(tmp_path, "base_models", method).iterdir())
        judges = read_evaluators_info(tmp_path / "evaluators")
        assert set(DEMO_STYLES) <= set(judges.style_labels)  # the judges, unlike the network, know the demo styles
        assert (method == DEFAULT_METHOD) == (run == tmp_path / "run")
        assert first.viewer.page == run / "viewer.html" and first.viewer.clips == rows
        second = run_demo(tmp_path, clips=400, size="tiny", method=method)
        assert second.run.transferred == 0 and second.run.manifest.rows == rows
        assert all(
            t.skipped == t.tasks for name, t in second.run.manifest.stages.items() if name in ("prepare", "transfer")
        )
    finally:
        if ray.is_initialized():
            ray.shutdown()
