"""The on-the-fly protocol of ``bench_onthefly.py`` repeated for every style of the synthetic corpus.

Usage: python lab/onthefly_styles.py --base-dir DIR --corpus DIR [--work /tmp/otf-styles]
       [--styles proud,old,...] [--split test|val|val+test] [--params JSON] [--lora-params JSON --lora-rank 4]
       [--no-content-clock] [--threads 2]

One example walk per style (a train-split clip), the same 36 held-out neutral clips (of ``--split``) of the other
contents, full fine-tuning (the ablation is ``bench_onthefly.py``'s); with ``--lora-params``, a LoRA variant beside it
on every style, so LoRA is compared with full fine-tuning on the hard styles too, not only on one. Per style: the
tempo measured from the example, SRA, CRA, root-relative MPJPE gain over the neutral input, the same gain on the
content's own clock (``tempo="content"``, the paper's transfer), the ceiling of such a clock-keeping transfer
(``mpjpe_oracle_timing_kept``) and the fine-tune time; then the mean over styles. The styles differ in how much of
them is posture and how much is clock and stride: the clock-keeping figures show what retiming adds.
Writes ``WORK/styles.json`` and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))  # lab reuses the quality benches' loaders
from bench_onthefly import HELD_OUT  # noqa: E402
from bench_onthefly import main as bench_one  # noqa: E402


def row(style: str, report: dict[str, Any]) -> dict[str, Any]:
    variants = {v["variant"]: v for v in report["variants"]}
    full = variants["full"]
    out = {
        "style": style,
        "tempo": full["tempo"],
        "sra": full["sra"],
        "cra": full["cra"],
        "mpjpe_gain": full["mpjpe"]["reduction_local"],
        "ceiling": report["mpjpe_oracle_timing_kept"]["reduction_local"],
        "legs_gain": full["mpjpe"]["reduction_legs"],
        "upper_gain": full["mpjpe"]["reduction_upper"],
        "finetune_s": full["finetune_s"],
        "example": report["example"]["id"],
        "content_splits": report["content_splits"],
    }
    if "content_clock" in variants:
        kept = variants["content_clock"]
        out |= {
            "content_clock_sra": kept["sra"],
            "content_clock_cra": kept["cra"],
            "content_clock_gain": kept["mpjpe"]["reduction_local"],
        }
    lora = next((v for name, v in variants.items() if name.startswith("lora")), None)
    if lora is not None:
        out |= {
            "lora_sra": lora["sra"],
            "lora_cra": lora["cra"],
            "lora_gain": lora["mpjpe"]["reduction_local"],
            "lora_share": lora["weights_share"],
            "lora_finetune_s": lora["finetune_s"],
        }
    return out


def table(rows: list[dict[str, Any]]) -> str:
    clock, lora = "content_clock_sra" in rows[0], "lora_sra" in rows[0]
    head = ["style", "tempo", "SRA", "CRA", "MPJPE gain", "upper body / legs gain"]
    head += ["content clock: SRA / CRA / gain"] if clock else []
    head += ["LoRA: SRA / CRA / gain (share of bytes)"] if lora else []
    head += ["ceiling (content clock)", "fine-tune s"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [
            r["style"],
            f"{r['tempo']:.2f}",
            f"{r['sra']:.0%}",
            f"{r['cra']:.0%}",
            f"{r['mpjpe_gain']:.1%}",
            f"{r['upper_gain']:.0%} / {r['legs_gain']:.0%}",
        ]
        if clock:
            cells.append(f"{r['content_clock_sra']:.0%} / {r['content_clock_cra']:.0%} / {r['content_clock_gain']:.1%}")
        if lora:
            cells.append(f"{r['lora_sra']:.0%} / {r['lora_cra']:.0%} / {r['lora_gain']:.1%} ({r['lora_share']:.1%})")
        cells += [f"{r['ceiling']:.1%}", f"{r['finetune_s']:.0f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    from motionaug.augment.synth.styles import STYLES

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base-dir", type=Path, required=True)
    parser.add_argument("--corpus", type=Path, required=True, help="the corpus the base models were trained on")
    parser.add_argument("--work", type=Path, default=Path("/tmp/otf-styles"))
    parser.add_argument("--styles", default=",".join(s for s in STYLES if s != "neutral"))
    parser.add_argument("--split", choices=sorted(HELD_OUT), default="test", help="split of the scored clips")
    parser.add_argument("--params", default="{}", help="JSON overrides of OnTheFlyParams")
    parser.add_argument("--lora-params", default=None, help="JSON overrides for a LoRA variant beside full fine-tuning")
    parser.add_argument("--lora-rank", type=int, default=4)
    parser.add_argument("--no-content-clock", action="store_true", help="skip the content-clock variant")
    parser.add_argument("--threads", type=int, default=int(os.environ.get("MOTIONAUG_TORCH_THREADS", "2")))
    args = parser.parse_args()
    skip = ["ablation", "throughput"] + (["content_clock"] if args.no_content_clock else [])
    if args.lora_params is None:
        skip, lora = [*skip, "lora"], []
    else:
        lora = ["--lora-params", args.lora_params, "--lora-rank", str(args.lora_rank)]
    rows = []
    for style in args.styles.split(","):
        work = args.work / style
        work.mkdir(parents=True, exist_ok=True)
        if not (work / "corpus").exists():
            (work / "corpus").symlink_to(args.corpus.resolve())
        report = bench_one(
            [
                "--work",
                str(work),
                "--base-dir",
                str(args.base_dir),
                "--style",
                style,
                "--split",
                args.split,
                "--params",
                args.params,
                "--skip",
                ",".join(skip),
                "--threads",
                str(args.threads),
                *lora,
            ]
        )
        rows.append(row(style, report))
    keys = [k for k, v in rows[0].items() if isinstance(v, float)]
    mean = {"style": "mean", "example": "", **{k: float(np.mean([r[k] for r in rows])) for k in keys}}
    summary = {"args": {k: str(v) for k, v in vars(args).items()}, "rows": rows, "mean": mean}
    (args.work / "styles.json").write_text(json.dumps(summary, indent=2))
    print(f"scored clips: held out, {args.split} split neutral clips {rows[0]['content_splits']}")
    print(table([*rows, mean]))


if __name__ == "__main__":
    main()
