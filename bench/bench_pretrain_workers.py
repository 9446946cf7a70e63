"""Pre-training steps/s: one process against ``motionaug pretrain --workers N`` (Ray Train, data-parallel).

Usage:
  python bench/bench_pretrain_workers.py --work DIR [--size tiny] [--clips 200] [--workers 2]
      [--prior-steps 100] [--encoder-steps 50] [--threads 2]

Generates the synthetic corpus (``generate_corpus(DIR/corpus, clips, seed=0)``) unless present, then runs the
command twice into fresh folders: ``--workers 1`` with ``threads`` torch threads, and ``--workers N`` on an
embedded Ray (each worker gets cpus // N threads). Prints steps/s of the prior and the motion encoder (from the
loss log's ``elapsed_s``: training steps only, no start-up) and each command's wall seconds (with Ray and
worker start-up). On a machine with as many cores as one process can use, N workers cannot be faster than one
process with N threads: they add gradient all-reduces and per-worker start-up; the figure shows the overhead,
the point being that the same command scales out on a cluster.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

from motionaug.augment.synth import generate_corpus


def stage_rates(out: Path) -> dict[str, float]:
    """Steps/s of each trained stage, from its last logged row (``done``: steps and elapsed training seconds)."""
    rates: dict[str, float] = {}
    for line in (out / "loss_log.jsonl").read_text(encoding="utf-8").splitlines():
        row = json.loads(line)
        if row.get("done") and row["stage"] in ("prior", "motion_encoder") and row.get("elapsed_s"):
            rates[row["stage"]] = round(row["step"] / row["elapsed_s"], 2)
    return rates


def run(args: argparse.Namespace, corpus: Path, workers: int) -> dict[str, object]:
    out = args.work / f"base_w{workers}"
    shutil.rmtree(out, ignore_errors=True)
    motionaug = str(Path(sys.executable).with_name("motionaug"))
    command = [motionaug, "pretrain", "--corpus", str(corpus), "--out", str(out), "--size", args.size]
    command += ["--set", f"prior_steps={args.prior_steps}", "--set", f"encoder_steps={args.encoder_steps}"]
    command += ["--set", "classifier_epochs=1"]
    if workers == 1:
        command += ["--set", f"threads={args.threads}"]
    else:
        command += ["--workers", str(workers)]
    started = time.perf_counter()
    subprocess.run(command, check=True, env={**os.environ, "RAY_USAGE_STATS_ENABLED": "0"})
    wall = round(time.perf_counter() - started, 1)
    return {"workers": workers, "wall_s": wall, "steps_per_s": stage_rates(out)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--size", default="tiny")
    parser.add_argument("--clips", type=int, default=200)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--prior-steps", type=int, default=100)
    parser.add_argument("--encoder-steps", type=int, default=50)
    parser.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    args = parser.parse_args()
    corpus = args.work / "corpus"
    if not (corpus / "Mean.npy").is_file():
        generate_corpus(corpus, args.clips, seed=0)
    results = [run(args, corpus, 1), run(args, corpus, args.workers)]
    print(json.dumps({"size": args.size, "load_avg": os.getloadavg(), "runs": results}, indent=2))


if __name__ == "__main__":
    main()
