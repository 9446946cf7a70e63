"""The on-the-fly protocol of ``bench_onthefly.py`` repeated for every style of the synthetic corpus.

Usage: python bench/bench_onthefly_styles.py --base-dir DIR --corpus DIR [--work /tmp/otf-styles]
       [--styles proud,old,...] [--params JSON] [--threads 2]

One example walk per style, the same 36 neutral clips of the other contents, full fine-tuning (the ablation
and LoRA variants are ``bench_onthefly.py``'s). Per style: the tempo measured from the example, SRA, CRA,
root-relative MPJPE gain over the neutral input, the same gain on the content's own clock (``tempo="content"``,
the paper's transfer), the ceiling of such a clock-keeping transfer (``mpjpe_oracle_timing_kept``) and the
fine-tune time; then the mean over styles. The styles differ in how much of them is posture and how much is
clock and stride: the clock-keeping figures show what retiming adds.
Writes ``WORK/styles.json`` and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from bench_onthefly import main as bench_one


def row(style: str, report: dict[str, Any]) -> dict[str, Any]:
    full = next(v for v in report["variants"] if v["variant"] == "full")
    kept = next(v for v in report["variants"] if v["variant"] == "content_clock")
    return {
        "style": style, "tempo": full["tempo"], "sra": full["sra"], "cra": full["cra"],
        "mpjpe_gain": full["mpjpe"]["reduction_local"], "content_clock_gain": kept["mpjpe"]["reduction_local"],
        "content_clock_sra": kept["sra"], "content_clock_cra": kept["cra"],
        "ceiling": report["mpjpe_oracle_timing_kept"]["reduction_local"],
        "legs_gain": full["mpjpe"]["reduction_legs"], "upper_gain": full["mpjpe"]["reduction_upper"],
        "finetune_s": full["finetune_s"], "example": report["example"]["id"],
    }  # fmt: skip


def table(rows: list[dict[str, Any]]) -> str:
    lines = ["| style | tempo | SRA | CRA | MPJPE gain | upper body / legs gain | content clock: SRA / CRA / gain "
             "| ceiling (content clock) | fine-tune s |", "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in rows:
        lines.append(
            f"| {r['style']} | {r['tempo']:.2f} | {r['sra']:.0%} | {r['cra']:.0%} | {r['mpjpe_gain']:.1%} | "
            f"{r['upper_gain']:.0%} / {r['legs_gain']:.0%} | {r['content_clock_sra']:.0%} / {r['content_clock_cra']:.0%} / "
            f"{r['content_clock_gain']:.1%} | {r['ceiling']:.1%} | {r['finetune_s']:.0f} |"
        )
    return "\n".join(lines)


def main() -> None:
    from augment.synth.styles import STYLES

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base-dir", type=Path, required=True)
    parser.add_argument("--corpus", type=Path, required=True, help="the corpus the base models were trained on")
    parser.add_argument("--work", type=Path, default=Path("/tmp/otf-styles"))
    parser.add_argument("--styles", default=",".join(s for s in STYLES if s != "neutral"))
    parser.add_argument("--params", default="{}", help="JSON overrides of OnTheFlyParams")
    parser.add_argument("--threads", type=int, default=int(os.environ.get("MOTIONAUG_TORCH_THREADS", "2")))
    args = parser.parse_args()
    rows = []
    for style in args.styles.split(","):
        work = args.work / style
        work.mkdir(parents=True, exist_ok=True)
        if not (work / "corpus").exists():
            (work / "corpus").symlink_to(args.corpus.resolve())
        report = bench_one([
            "--work", str(work), "--base-dir", str(args.base_dir), "--style", style, "--params", args.params,
            "--skip", "ablation,lora,throughput", "--threads", str(args.threads),
        ])  # fmt: skip
        rows.append(row(style, report))
    keys = ("tempo", "sra", "cra", "mpjpe_gain", "content_clock_sra", "content_clock_cra", "content_clock_gain", "ceiling",
            "legs_gain", "upper_gain", "finetune_s")
    mean = {"style": "mean", "example": "", **{k: float(np.mean([r[k] for r in rows])) for k in keys}}
    summary = {"args": {k: str(v) for k, v in vars(args).items()}, "rows": rows, "mean": mean}
    (args.work / "styles.json").write_text(json.dumps(summary, indent=2))
    print(table([*rows, mean]))


if __name__ == "__main__":
    main()
