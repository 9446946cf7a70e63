"""`motionaug demo` end to end at its tiny size, for every demo method: real Ray, real shards, and a rerun that
finishes at once.

tests/test_demo.py runs ``check_demo`` for the default method; the other methods' demo paths (their base models
on the corpus without the demo styles, their per-style step, transfers, export, viewer) run here, with what each
took:

    .venv/bin/python bench/bench_demo.py                       # every method in DEMO_METHODS
    .venv/bin/python bench/bench_demo.py --methods onthefly
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import pyarrow.parquet as pq

from motionaug.augment.corpus import HumanML3DReader
from motionaug.augment.training.evaluators import read_evaluators_info

CLIPS = 400  # enough for a walk and a wave per demo style, so every clip has an example of its kind


def check_demo(out: Path, method: str) -> float:
    """Run the tiny demo into the empty folder ``out`` twice; assert what a user relies on; seconds of the first run.

    The first run builds the corpus, the corpus without the demo styles (what the method trains on), the judges,
    the base models, every style's step, the transfers, the export and the viewer; the second finds it all done."""
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    from motionaug.workflows.demo import DEFAULT_METHOD, DEMO_STYLES, method_folder, run_demo

    run = method_folder(out, "run", method)
    try:
        started = time.perf_counter()
        first = run_demo(out, clips=CLIPS, size="tiny", method=method)
        seconds = time.perf_counter() - started
        neutral = [c for c in HumanML3DReader(first.corpus) if c.style == "neutral" and 40 <= c.n_frames <= 199]
        rows = pq.read_table(run / "shards").num_rows
        assert rows == first.run.manifest.rows == len(neutral) * len(DEMO_STYLES)
        assert first.run.notes == []  # a walk and a wave per style: every clip has an example of its kind
        assert first.export.stylized > 0 and (method_folder(out, "expanded", method) / "train.txt").is_file()
        assert set(pq.read_table(run / "shards", columns=["method"]).column("method").to_pylist()) == {method}
        if method != "stats":  # the stats method trains nothing
            trained_on = {c.style for c in HumanML3DReader(out / "corpus-without-demo-styles")}
            assert trained_on and not trained_on & set(DEMO_STYLES)  # every demo style is new to the network
            assert any(method_folder(out, "base_models", method).iterdir())
        judges = read_evaluators_info(out / "evaluators")
        assert set(DEMO_STYLES) <= set(judges.style_labels)  # the judges, unlike the network, know the demo styles
        assert (method == DEFAULT_METHOD) == (run == out / "run")
        assert first.viewer.page == run / "viewer.html" and first.viewer.clips == rows
        second = run_demo(out, clips=CLIPS, size="tiny", method=method)
        assert second.run.transferred == 0 and second.run.manifest.rows == rows
        assert all(
            t.skipped == t.tasks for name, t in second.run.manifest.stages.items() if name in ("prepare", "transfer")
        )
        return seconds
    finally:
        ray = sys.modules.get("ray")  # imported by the demo, after it set the embedded Ray to bind 127.0.0.1
        if ray is not None and ray.is_initialized():
            ray.shutdown()


def main() -> None:
    from motionaug.workflows.demo import DEMO_METHODS

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--methods", nargs="*", default=list(DEMO_METHODS), choices=list(DEMO_METHODS))
    args = parser.parse_args()
    for method in args.methods:
        with tempfile.TemporaryDirectory(prefix=f"demo-{method}-") as scratch:
            seconds = check_demo(Path(scratch), method)
        print(f"{method}: tiny demo end to end and resumed, first run {seconds:.0f} s", flush=True)


if __name__ == "__main__":
    main()
