"""UMSD: a fixed-step training run, transfer throughput and the cost of adding a style.

Usage: python bench/bench_umsd.py [--corpus /tmp/umsd/synth] [--clips 400] [--preset default|large|tiny]
       [--steps 2000] [--hold-out old] [--transfer-clips 32] [--ddim-steps 50]
       [--model-dir DIR] [--skip train,prepare,transfer] [--out bench_umsd.json] [--quick]

(a) Training: ``UmsdMethod.train`` on the corpus's train split at ``--steps`` (a fixed count; no time cap), with
``--hold-out`` styles excluded (zero-shot, paper sec. 4.4); reports wall time, steps/s and every loss term
(rec, Eq. 10 dcc, Eq. 11 dsc, Eq. 12 pos/vel/foot, total) at the first and last history points. A corpus that does
not exist is generated first (synthetic, ``--clips`` clips, seed 0). An already trained ``--model-dir`` with the same
corpus and config is reused (then the training time is not measured again).
(b) Adding a style: ``UmsdMethod.prepare`` for the held-out style from one and from three example clips (no
gradient steps: validation, normalisation, writing the artefact; the network load and the fingerprint of its
files are part of it).
(c) Transfer: ``load`` + ``transfer`` of ``--transfer-clips`` neutral test clips to the held-out style, DDIM
``--ddim-steps`` from pure noise, in batches of 16, after a warm-up call; clips/s in fp32.

The machine's load average is recorded next to the figures: on a shared 2-core box the times mostly measure the
scheduler. ``--quick``: a seconds-long smoke of every part (48 clips, 5 steps at the default preset, 10 DDIM steps).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from motionaug.augment.corpus import Corpus, MotionClip
from motionaug.augment.device import cpu_has_bf16
from motionaug.augment.methods.base import TrainingSpec
from motionaug.augment.methods.umsd import load_umsd, read_artifact
from motionaug.augment.methods.umsd.method import UmsdMethod
from motionaug.augment.outputs.shards import TransferOutput
from motionaug.augment.synth import STYLE_WORDS, generate_corpus
from motionaug.schemas.styles import StyleSpec

PRESETS: dict[str, tuple[str, dict[str, Any]]] = {  # (network size, training settings)
    "default": ("small", {}),  # d_model 64, 3 MSM blocks, batch 8 per term, 120-frame crops
    "large": ("paper", {"batch_size": 16}),
    "tiny": ("tiny", {"batch_size": 2, "max_frames": 40}),
}


def style_spec(name: str, examples: Sequence[MotionClip]) -> StyleSpec:
    words = STYLE_WORDS[name].model_dump() if name in STYLE_WORDS else {"adjective": name}
    return StyleSpec(
        name=name,
        words=words,
        examples=[{"source": e.id, "description": f"a person moves in a {name} way"} for e in examples],
    )


def bench_training(method: UmsdMethod, corpus: Path, model_dir: Path, size: str) -> dict[str, Any]:
    last = {"t": time.perf_counter()}
    every = max(1, method.params.train.steps // 10)

    def progress(stage: str, step: int, total: int, metrics: dict[str, float]) -> None:
        if step % every == 0 or step == total:
            now = time.perf_counter()
            print(f"  step {step}/{total} ({now - last['t']:.1f}s) { ({k: round(v, 4) for k, v in metrics.items()}) }")
            last["t"] = now

    load_before = list(os.getloadavg())
    reused = method.is_trained(model_dir)
    start = time.perf_counter()
    method.train(corpus, model_dir, TrainingSpec(size=size, seed=0), progress)
    seconds = time.perf_counter() - start
    info = read_artifact(model_dir)
    return {
        "reused": reused,
        "data": info.data,
        "config": info.train.model_dump(mode="json"),
        "parameters": sum(p.numel() for p in load_umsd(model_dir).net.parameters()),
        "steps": info.train.steps,
        "seconds": info.seconds if reused else seconds,
        "steps_per_s": info.train.steps / (info.seconds if reused else seconds),
        "first": info.history[0],
        "last": info.history[-1],
        "loadavg_before": load_before,
        "loadavg_after": list(os.getloadavg()),
        "model_dir": str(model_dir),
    }


def bench_prepare(method: UmsdMethod, model_dir: Path, examples: list[MotionClip], work: Path) -> dict[str, Any]:
    rows = {}
    for n in sorted({1, min(3, len(examples))}):
        spec = style_spec(examples[0].style or "style", examples[:n])
        start = time.perf_counter()
        method.prepare(spec, examples[:n], model_dir, [], work / f"style_{n}")
        rows[f"{n} example(s)"] = {
            "seconds": time.perf_counter() - start,
            "frames": sum(e.n_frames for e in examples[:n]),
        }
    return rows


def bench_transfer(
    params: dict[str, Any], model_dir: Path, artifact: Path, content: list[MotionClip]
) -> dict[str, Any]:
    model = UmsdMethod(params).load(artifact, model_dir)
    model.transfer(content[:2], seed=0)  # warm-up
    start = time.perf_counter()
    outputs = model.transfer(content, seed=0)
    seconds = time.perf_counter() - start
    done = [o for o in outputs if isinstance(o, TransferOutput)]
    return {
        "clips": len(content),
        "transferred": len(done),
        "frames": sum(o.motion.shape[0] for o in done),
        "seconds": seconds,
        "clips_per_s": len(done) / seconds,
        "loadavg": list(os.getloadavg()),
    }


def markdown(result: dict[str, Any]) -> str:
    lines = [f"UMSD bench, torch {result['torch']}, {result['threads']} thread(s), cpu_bf16={result['cpu_bf16']}", ""]
    if "train" in result:
        tr = result["train"]
        cfg = tr["config"]
        lines += [
            f"Training: {tr['data']['clips']} clips (held out: {cfg['exclude_styles']}), {tr['steps']} steps, "
            f"{cfg['denoiser']} denoiser, {tr['parameters']} parameters, d_model {cfg['d_model']}, "
            f"{cfg['msm_blocks']} blocks, "
            f"batch {cfg['batch_size']} per term, crops {cfg['max_frames']} frames: {tr['seconds']:.1f} s "
            f"({tr['steps_per_s']:.3f} steps/s){' (reused folder: its recorded time)' if tr['reused'] else ''}, "
            f"load average {tr['loadavg_before'][0]:.1f}",
            "",
            "| losses (mean over a history interval) | " + " | ".join(k for k in tr["last"] if k != "step") + " |",
            "|---|" + "---:|" * (len(tr["last"]) - 1),
        ]
        for label in ("first", "last"):
            row = tr[label]
            values = " | ".join(f"{v:.4f}" for k, v in row.items() if k != "step")
            lines.append(f"| {label} (step {int(row['step'])}) | {values} |")
        lines.append("")
    if "prepare" in result:
        lines += ["| adding a style (prepare) | example frames | seconds |", "|---|---:|---:|"]
        for name, row in result["prepare"].items():
            lines.append(f"| {name} | {row['frames']} | {row['seconds']:.3f} |")
        lines.append("")
    if "transfer" in result:
        tf = result["transfer"]
        lines += [
            f"Transfer: {tf['ddim_steps']} DDIM steps from pure noise, batches of {tf['batch_size']}",
            "",
            "| precision | clips | frames | seconds | clips/s | load average |",
            "|---|---:|---:|---:|---:|---:|",
        ]
        for name in ("fp32",):
            if name in tf:
                r = tf[name]
                lines.append(
                    f"| {name} | {r['transferred']}/{r['clips']} | {r['frames']} | {r['seconds']:.2f} | "
                    f"{r['clips_per_s']:.3f} | {r['loadavg'][0]:.1f} |"
                )
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--corpus", type=Path, default=Path("/tmp/umsd/synth"))
    parser.add_argument("--clips", type=int, default=400, help="clips of a generated corpus")
    parser.add_argument("--preset", choices=sorted(PRESETS), default="default")
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--hold-out", default="old", help="style excluded from training and prepared zero-shot")
    parser.add_argument("--transfer-clips", type=int, default=32)
    parser.add_argument("--ddim-steps", type=int, default=50)
    parser.add_argument("--model-dir", type=Path, default=None)
    parser.add_argument("--skip", default="", help="comma list of: train, prepare, transfer")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args(argv)
    skip = {s.strip() for s in args.skip.split(",") if s.strip()}
    if args.quick:
        args.clips, args.steps, args.ddim_steps = 48, 5, 10
        args.transfer_clips = min(args.transfer_clips, 8)
    torch.set_num_threads(args.threads)
    work = Path(tempfile.mkdtemp(prefix="bench_umsd_"))
    if not (args.corpus / "new_joint_vecs").is_dir():
        print(f"generating a {args.clips}-clip synthetic corpus in {args.corpus}", flush=True)
        generate_corpus(args.corpus, args.clips, seed=0)
    model_dir = args.model_dir or work / "trained"
    size, preset = PRESETS[args.preset]
    train = {**preset, "steps": args.steps}
    train |= {"exclude_styles": [args.hold_out], "log_every": max(1, args.steps // 20)}
    params = {"train": train, "ddim_steps": args.ddim_steps, "batch_size": 16}
    method = UmsdMethod(params)
    result: dict[str, Any] = {
        "python": platform.python_version(),
        "torch": torch.__version__,
        "cpus": os.cpu_count(),
        "threads": args.threads,
        "cpu_bf16": cpu_has_bf16(),
        "preset": args.preset,
    }
    if "train" not in skip:
        print(f"training {args.steps} steps ({args.preset}) on {args.corpus} -> {model_dir}", flush=True)
        result["train"] = bench_training(method, args.corpus, model_dir, size)
    elif not method.is_trained(model_dir):
        raise SystemExit(f"--skip train needs a trained --model-dir, {model_dir} has none")
    everything = list(Corpus(args.corpus))
    examples = [c for c in everything if c.style == args.hold_out][:3]
    if not examples:
        raise SystemExit(f"the corpus has no clip of style {args.hold_out!r}")
    if "prepare" not in skip:
        result["prepare"] = bench_prepare(method, model_dir, examples, work)
    if "transfer" not in skip:
        test_ids = set((args.corpus / "test.txt").read_text().split()) if (args.corpus / "test.txt").is_file() else None
        neutral = [c for c in everything if c.style == "neutral" and (test_ids is None or c.id in test_ids)]
        neutral += [c for c in everything if c.style == "neutral" and c not in neutral]
        content = neutral[: args.transfer_clips]
        spec = style_spec(args.hold_out, examples[:1])
        artifact = method.prepare(spec, examples[:1], model_dir, [], work / "style").folder
        result["transfer"] = {"ddim_steps": args.ddim_steps, "batch_size": 16}
        result["transfer"]["fp32"] = bench_transfer(params, model_dir, artifact, content)
    print(markdown(result))
    if args.out:
        args.out.write_text(json.dumps(result, indent=1), encoding="utf-8")
    return result


if __name__ == "__main__":
    main()
