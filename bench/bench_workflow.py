"""Transfer-stage scaling of the Ray workflow on this machine.

Measures, for each worker count (an embedded Ray cluster with that many CPUs, one CPU per transfer task):
throughput of the transfer stage (stylized clips per second), Ray overhead per task as a fraction of task
time (driver wall time x workers minus in-task time, over in-task time; plus a no-op task round trip),
the artefact load time as a fraction of a unit, and peak resident memory per worker.

    .venv/bin/python bench/bench_workflow.py --clips 512 --workers 1 2 --method stats
    .venv/bin/python bench/bench_workflow.py --clips 64 --unit-size 32 --method onthefly --set method.params.max_steps=2

Run it when the machine is quiet; results go to stdout as JSON (and --out FILE).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

STYLES = [
    {"name": "proud", "words": {"adjective": "proud", "adverb": "proudly"},
     "examples": [{"source": "000004", "description": "a person walks proudly"}]},
    {"name": "old", "words": {"adjective": "old", "phrases": ["like an old person"]},
     "examples": [{"source": "000008", "description": "a person walks like an old person"}]},
]  # fmt: skip


def noop_round_trip(n: int = 50) -> float:
    """Median seconds of submitting and getting a task that does nothing."""
    import ray

    @ray.remote(num_cpus=1)
    def noop() -> None:
        return None

    ray.get(noop.remote())  # warm a worker
    times = []
    for _ in range(n):
        start = time.perf_counter()
        ray.get(noop.remote())
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def measure(corpus: Path, workdir: Path, workers: int, args: argparse.Namespace) -> dict:
    import ray

    from schemas.run_config import load_run_config
    from workflows.ray_executor import execute_run

    data = {
        "corpus": {"path": str(corpus)}, "styles": STYLES, "method": {"name": args.method},
        "compute": {"num_cpus": workers, "unit_size": args.unit_size, "batch_size": args.batch_size},
        "output": str(workdir / f"run-{workers}"), "seed": 0,
    }  # fmt: skip
    config = load_run_config(None, args.set or [], data=data)
    ray.init(address="local", num_cpus=workers, include_dashboard=False, log_to_driver=False)
    try:
        noop = noop_round_trip()
        summary = execute_run(config, force=True)
    finally:
        ray.shutdown()
    manifest = summary.manifest
    transfer = manifest.stages["transfer"]
    in_task = sum(s.seconds for s in manifest.shards)
    finetune = manifest.stages["finetune"].seconds
    busy_wall = max(transfer.seconds - finetune, 1e-9) * workers  # fine-tunes overlap the first transfers
    return {
        "workers": workers, "rows": manifest.rows, "tasks": len(manifest.shards),
        "transfer_stage_s": round(transfer.seconds, 3), "finetune_s": round(finetune, 3),
        "clips_per_s": round(manifest.rows / transfer.seconds, 2),
        "mean_task_s": round(in_task / max(len(manifest.shards), 1), 3),
        "ray_overhead_fraction": round(max(busy_wall - in_task, 0.0) / max(in_task, 1e-9), 3),
        "noop_task_round_trip_ms": round(noop * 1000, 2),
        "load_fraction_of_unit": round(sum(s.load_seconds for s in manifest.shards) / max(in_task, 1e-9), 4),
        "peak_rss_mb_per_worker": round(max(s.peak_rss_mb for s in manifest.shards), 1),
    }  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clips", type=int, default=512)
    parser.add_argument("--unit-size", type=int, default=256)
    parser.add_argument("--batch-size", type=int, default=32)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--method", default="stats")
    parser.add_argument("--set", action="append", help="Config override key.sub=value (repeatable).")
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    import torch

    torch.set_num_threads(1)
    from augment.synth import generate_corpus

    with tempfile.TemporaryDirectory(prefix="bench-workflow-") as tmp:
        workdir = Path(tmp)
        start = time.perf_counter()
        generate_corpus(workdir / "corpus", args.clips, seed=0)
        results = {
            "method": args.method, "clips": args.clips, "unit_size": args.unit_size, "batch_size": args.batch_size,
            "styles": len(STYLES), "cpu_count": os.cpu_count(), "corpus_s": round(time.perf_counter() - start, 2),
            "runs": [measure(workdir / "corpus", workdir, w, args) for w in args.workers],
        }  # fmt: skip
    runs = results["runs"]
    if len(runs) > 1:
        results["speedup"] = round(runs[-1]["clips_per_s"] / runs[0]["clips_per_s"], 2)
    text = json.dumps(results, indent=1)
    print(text)
    if args.out:
        args.out.write_text(text + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
