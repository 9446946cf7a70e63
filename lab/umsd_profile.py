"""Seconds per UMSD training step at chosen sizes, and where a step's time goes (torch.profiler).

Usage: python lab/umsd_profile.py --corpus CORPUS [--neutral normal] [--steps 6] [--threads 1]
       [--profile] [key=value ...]

``key=value``: ``UmsdTrainConfig`` fields (e.g. ``max_frames=96 batch_size=6``). Every clip of ``CORPUS`` is used
(the speed does not depend on the split). After two warm-up steps, ``--steps`` sampled steps are timed at
``--threads`` (1); ``--profile`` adds the ten most expensive operators of one forward + backward. The machine's
load average is printed beside the figures: on a shared machine the times mostly measure the scheduler.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from dataclasses import replace
from pathlib import Path

import torch

from motionaug.augment.corpus import Corpus
from motionaug.augment.methods.umsd import UmsdTrainConfig, UmsdTrainer, prepare_data
from motionaug.schemas.run_config import apply_overrides


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--corpus", type=Path, required=True)
    parser.add_argument("--neutral", default="normal")
    parser.add_argument("--steps", type=int, default=6)
    parser.add_argument("--profile", action="store_true")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (training's ``threads``)")
    parser.add_argument("fields", nargs="*", help="UmsdTrainConfig key=value")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    fields = apply_overrides({}, args.fields)
    config = UmsdTrainConfig(**fields)
    clips = [replace(c, style="neutral") if c.style == args.neutral else c for c in Corpus(args.corpus)]
    torch.manual_seed(0)
    trainer = UmsdTrainer(prepare_data(clips, config), config)
    for _ in range(2):
        trainer.train_step(trainer.sample())
    load = os.getloadavg()[0]
    start = time.perf_counter()
    for _ in range(args.steps):
        trainer.train_step(trainer.sample())
    seconds = (time.perf_counter() - start) / args.steps
    result = {
        "fields": fields,
        "threads": args.threads,
        "parameters": sum(p.numel() for p in trainer.net.parameters()),
        "s_per_step": round(seconds, 3),
        "steps_per_s": round(1 / seconds, 3),
        "load": [round(load, 1), round(os.getloadavg()[0], 1)],
    }
    if args.profile:
        batch = trainer.sample()
        trainer.net.train()
        with torch.profiler.profile() as prof:
            loss = trainer.losses(batch)["total"]
            trainer.opt.zero_grad()
            loss.backward()
        print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=10))
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
