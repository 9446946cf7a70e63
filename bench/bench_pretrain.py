"""Pretraining wall time and held-out figures, on the default synthetic corpus or on Bandai evaluators.

Usage:
  python bench/bench_pretrain.py synthetic --work DIR [--size small] [--clips 1000] [--threads 2] [--set key=value ...]
      generates the synthetic corpus (``generate_corpus(DIR/corpus, clips, seed=0)``) unless present, pretrains all
      three stages into DIR/base (fresh), and prints per-stage seconds, metrics and the load average.
      Target: ``small`` finishes in <= 15 minutes on 2 cores.
  python bench/bench_pretrain.py bandai --corpus DIR --work DIR [--threads 2]
      evaluators alone on an imported Bandai corpus (``motionaug corpus import-bvh ... --out DIR``), hash split 80/20.

Then: python bench/bench_t2m_quality.py --base DIR/base --corpus DIR/corpus
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from pathlib import Path

import torch

from motionaug.augment.synth import generate_corpus
from motionaug.augment.training.pretrain import PretrainConfig, fit_evaluators, pretrain
from motionaug.schemas.run_config import apply_overrides


class StageTimer:
    """Progress callback: seconds per stage, and a line to stderr every ``every`` steps."""

    def __init__(self, every: int = 100) -> None:
        self.start = time.perf_counter()
        self.seen: dict[str, float] = {}
        self.every = every

    def __call__(self, stage: str, step: int, total: int, metrics: dict[str, float]) -> None:
        self.seen.setdefault(stage, time.perf_counter())
        if step % self.every == 0 or step == total:
            elapsed = time.perf_counter() - self.start
            shown = " ".join(f"{k}={v:.4g}" for k, v in metrics.items())
            print(f"[{elapsed:7.1f}s] {stage} {step}/{total} {shown}", file=sys.stderr, flush=True)

    def stage_seconds(self, end: float) -> dict[str, float]:
        starts = sorted(self.seen.items(), key=lambda kv: kv[1])
        ends = [t for _, t in starts[1:]] + [end]
        return {name: round(stop - begin, 1) for (name, begin), stop in zip(starts, ends)}


def synthetic(args: argparse.Namespace) -> dict[str, object]:
    work = args.work
    corpus = work / "corpus"
    if not (corpus / "Mean.npy").is_file():
        shutil.rmtree(corpus, ignore_errors=True)
        generate_corpus(corpus, args.clips, seed=0)
    base = work / "base"
    shutil.rmtree(base, ignore_errors=True)
    config = PretrainConfig.for_size(args.size, threads=args.threads, **apply_overrides({}, args.set))
    timer = StageTimer()
    start = time.perf_counter()
    info = pretrain(corpus, base, config, progress=timer)
    end = time.perf_counter()
    return {
        "size": args.size,
        "total_seconds": round(end - start, 1),
        "stage_seconds": timer.stage_seconds(end),
        "metrics": info.metrics,
        "config": config.model_dump(exclude_defaults=True),
        "load": os.getloadavg(),
    }


def bandai(args: argparse.Namespace) -> dict[str, object]:
    config = PretrainConfig(threads=args.threads, **apply_overrides({}, args.set))
    start = time.perf_counter()
    metrics = fit_evaluators(args.corpus, args.work, config)
    return {"metrics": metrics, "seconds": round(time.perf_counter() - start, 1), "load": os.getloadavg()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    syn = sub.add_parser("synthetic")
    syn.add_argument("--work", type=Path, required=True)
    syn.add_argument("--size", default="small")
    syn.add_argument("--clips", type=int, default=1000)
    ban = sub.add_parser("bandai")
    ban.add_argument("--corpus", type=Path, required=True)
    ban.add_argument("--work", type=Path, required=True)
    for p in (syn, ban):
        p.add_argument("--threads", type=int, default=os.cpu_count())
        p.add_argument("--set", nargs="*", default=[], help="PretrainConfig overrides, key=value")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    report = synthetic(args) if args.command == "synthetic" else bandai(args)
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
