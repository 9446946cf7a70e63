"""Transfer-stage scaling of the Ray workflow on this machine.

The run is done once in full (plan, fine-tunes, transfers). Then, for each worker count (an embedded Ray cluster
with that many CPUs, one CPU and one torch thread per transfer task), its shards are removed and the run is
resumed: only the transfer stage runs again, with the style artefacts already made, so the figures are the
transfer stage's alone. Each Ray is started and its workers warmed first (one concurrent task per worker; the
time is reported as ``worker_start_s``), as the fine-tune tasks do in a real run. Reported per worker count:
throughput (stylized clips per second), Ray overhead per task as a fraction of task time (stage wall time x
workers minus in-task time, over in-task time; plus a no-op task round trip), the artefact load time as a
fraction of a unit, and peak resident memory per worker.

    .venv/bin/python bench/bench_workflow.py --method onthefly --base-models /tmp/t2m-full/base --clips 512
    .venv/bin/python bench/bench_workflow.py --clips 512 --method stats

Run it when the machine is quiet; results go to stdout as JSON (and --out FILE).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

STYLES = [
    {
        "name": "proud",
        "words": {"adjective": "proud", "adverb": "proudly"},
        "examples": [{"source": "000151", "description": "a person walks proudly"}],
    },
    {
        "name": "old",
        "words": {"adjective": "old", "phrases": ["like an old person"]},
        "examples": [{"source": "000084", "description": "an old person walks"}],
    },
]


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


def warm_workers(workers: int) -> tuple[float, int]:
    """Start every worker process and import the stage code in it: (seconds, distinct worker processes).

    In a real run the fine-tune tasks start the workers before any transfer; these transfer-only reruns would
    otherwise time the second worker's start-up (its process and the torch import) as transfer time.
    """
    import ray

    from motionaug.workflows.ray_executor import warm_worker

    @ray.remote(num_cpus=1)
    def ready() -> int:
        warm_worker()  # the setup hook's own import; a no-op when the hook already ran
        time.sleep(0.5)  # hold the CPU so that each call lands on its own worker
        return os.getpid()

    start = time.perf_counter()
    pids = ray.get([ready.remote() for _ in range(workers)])
    return time.perf_counter() - start, len(set(pids))


def run_config(corpus: Path, out: Path, workers: int, args: argparse.Namespace) -> Any:
    from motionaug.schemas.run_config import load_run_config

    data: dict[str, Any] = {
        "corpus": {"path": str(corpus), "filters": {"source_styles": ["neutral"]}},
        "styles": STYLES,
        "method": {"name": args.method},
        "compute": {"num_cpus": workers, "unit_size": args.unit_size, "batch_size": args.batch_size},
        "output": str(out),
        "seed": 0,
    }
    if args.base_models:
        data["base_models"] = {"path": str(args.base_models), "pretrain_if_missing": False}
    return load_run_config(None, args.set or [], data=data)


def execute(config: Any, workers: int, force: bool = False, warm: bool = True) -> tuple[Any, dict[str, float]]:
    """One run in a fresh embedded Ray of ``workers`` CPUs, workers started first; the summary and Ray timings."""
    import ray

    from motionaug.workflows.ray_executor import embedded_runtime_env, execute_run

    ray.init(
        address="local",
        num_cpus=workers,
        include_dashboard=False,
        log_to_driver=False,
        runtime_env=embedded_runtime_env(),
    )
    try:
        warm_s, started = warm_workers(workers) if warm else (0.0, 0)
        timings = {"worker_start_s": warm_s, "workers_started": started, "noop_round_trip_s": noop_round_trip()}
        return execute_run(config, force=force), timings
    finally:
        ray.shutdown()


def drop_shards(run_dir: Path) -> None:
    """Remove the transfer stage's outputs so that resuming runs exactly that stage again."""
    from motionaug.augment.outputs.run_dir import RunDir

    run = RunDir(run_dir)
    for path in (run.shards_dir, run.rejects_dir):
        shutil.rmtree(path, ignore_errors=True)
    for path in (run.manifest_path, run.success_path):
        path.unlink(missing_ok=True)


def measure(config: Any, workers: int, warm: bool) -> dict[str, Any]:
    drop_shards(config.output)
    compute = config.compute.model_copy(update={"num_cpus": workers})
    summary, ray_timings = execute(config.model_copy(update={"compute": compute}), workers, warm=warm)
    manifest = summary.manifest
    transfer = manifest.stages["transfer"]
    in_task = sum(s.seconds for s in manifest.shards)
    busy_wall = transfer.seconds * min(workers, len(manifest.shards))
    return {
        "workers": workers,
        "rows": manifest.rows,
        "tasks": len(manifest.shards),
        "finetune_tasks_run": manifest.stages["prepare"].tasks - manifest.stages["prepare"].skipped,
        "transfer_stage_s": round(transfer.seconds, 2),
        "clips_per_s": round(manifest.rows / transfer.seconds, 2),
        "mean_task_s": round(in_task / max(len(manifest.shards), 1), 2),
        "ray_overhead_fraction": round(max(busy_wall - in_task, 0.0) / max(in_task, 1e-9), 4),
        "noop_task_round_trip_ms": round(ray_timings["noop_round_trip_s"] * 1000, 2),
        "worker_start_s": round(ray_timings["worker_start_s"], 2),
        "workers_started": ray_timings["workers_started"],
        "load_fraction_of_unit": round(sum(s.load_seconds for s in manifest.shards) / max(in_task, 1e-9), 4),
        "peak_rss_mb_per_worker": round(max(s.peak_rss_mb for s in manifest.shards), 1),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clips", type=int, default=512, help="synthetic corpus size (neutral clips are transferred)")
    parser.add_argument("--corpus", type=Path, help="use this synthetic corpus instead of rendering one")
    parser.add_argument("--unit-size", type=int, default=256)
    parser.add_argument("--batch-size", type=int, default=32)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--method", default="onthefly")
    parser.add_argument("--base-models", type=Path, help="pre-trained base models (onthefly)")
    parser.add_argument("--set", action="append", help="Config override key.sub=value (repeatable).")
    parser.add_argument("--work", type=Path, help="keep the runs here (default: a temporary folder)")
    parser.add_argument("--out", type=Path)
    parser.add_argument("--cold", action="store_true", help="do not start the workers before timing the transfers")
    args = parser.parse_args()
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    from motionaug.augment.synth import generate_corpus

    with tempfile.TemporaryDirectory(prefix="bench-workflow-") as tmp:
        workdir = args.work or Path(tmp)
        corpus = args.corpus or workdir / "corpus"
        start = time.perf_counter()
        if args.corpus is None and not (corpus / "labels.jsonl").is_file():
            generate_corpus(corpus, args.clips, seed=0)
        corpus_s = time.perf_counter() - start
        config = run_config(corpus, workdir / "run", max(args.workers), args)
        start = time.perf_counter()
        first, _ = execute(config, max(args.workers), force=True)
        results: dict[str, Any] = {
            "method": args.method,
            "clips": first.manifest.rows // len(STYLES),
            "unit_size": args.unit_size,
            "batch_size": args.batch_size,
            "styles": len(STYLES),
            "cpu_count": os.cpu_count(),
            "corpus_s": round(corpus_s, 2),
            "full_run_s": round(time.perf_counter() - start, 1),
            "finetune_stage_s": round(first.manifest.stages["prepare"].seconds, 1),
            "runs": [measure(config, w, warm=not args.cold) for w in args.workers],
            "load": os.getloadavg(),
        }
    runs = results["runs"]
    if len(runs) > 1:
        results["speedup"] = round(runs[-1]["clips_per_s"] / runs[0]["clips_per_s"], 2)
    text = json.dumps(results, indent=1)
    print(text)
    if args.out:
        args.out.write_text(text + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
