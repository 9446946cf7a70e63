"""Seconds per UMSD training step for several training configs, measured in one run (same machine state).

  python lab/umsd_step.py --corpus SYNTH/corpus [--preset bandai] [--steps 30] [--threads 1]
      --variant "skip=content w_dsc=0 lr=0.001" --variant "skip=content w_dsc=0 lr=0.001 synthetic_pairs=true w_spec=10"

Each variant (``UmsdTrainConfig`` overrides on top of ``--preset``) prepares the corpus's train split (the
partners rendered when ``synthetic_pairs``; its seconds reported), builds the trainer, takes 5 warm-up steps and
times ``--steps`` more. A full run's length is about ``steps x s_per_step + prepare_s``; the machine's load
average is recorded beside the figures, since on a shared 2-core machine it moves them.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import torch
from umsd_quality import PRESETS, load_clips, splits  # noqa: E402

from motionaug.augment.methods.umsd.training import UmsdTrainConfig, UmsdTrainer, prepare_data  # noqa: E402
from motionaug.schemas.run_config import apply_overrides

WARMUP = 5


def time_variant(clips: list, preset: str, sets: str, steps: int, threads: int) -> dict[str, object]:
    config = UmsdTrainConfig(
        **{**PRESETS[preset], "steps": steps, "threads": threads, **apply_overrides({}, sets.split())}
    )
    start = time.perf_counter()
    data = prepare_data(clips, config)
    prepare_s = time.perf_counter() - start
    torch.manual_seed(config.seed)
    trainer = UmsdTrainer(data, config)
    for _ in range(WARMUP):
        trainer.train_step(trainer.sample())
    start = time.perf_counter()
    for _ in range(steps):
        trainer.train_step(trainer.sample())
    return {
        "variant": sets,
        "s_per_step": (time.perf_counter() - start) / steps,
        "prepare_s": prepare_s,
        "clips": len(data.ids),
    }


def main(argv: list[str] | None = None) -> list[dict[str, object]]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--corpus", type=Path, required=True)
    parser.add_argument("--preset", choices=sorted(PRESETS), default="bandai")
    parser.add_argument("--steps", type=int, default=30)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--variant", action="append", required=True, help="space-separated key=value overrides")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    by_id = load_clips(args.corpus)
    clips = [by_id[i] for i in splits(args.corpus)["train"] if i in by_id]
    rows = []
    for sets in args.variant:
        row = time_variant(clips, args.preset, sets, args.steps, args.threads)
        row |= {"threads": args.threads, "load": os.getloadavg()[0]}
        print(json.dumps(row), flush=True)
        rows.append(row)
    return rows


if __name__ == "__main__":
    main()
