"""Style-ERD: per-frame latency of the online step, and a fixed-step training run on the synthetic corpus.

Usage: python bench/bench_erd.py [--corpus /tmp/erd/synth] [--steps 3000] [--frames 3000] [--model-dir DIR]
       [--out bench_erd.json] [--skip latency,train] [--quick]

(a) Latency, batch 1, ``torch.set_num_threads(1)``, after a warm-up: p50/p99 wall time per frame over
``--frames`` frames of the network step (``ErdNetwork.step``) at the paper's sizes (supp. A: latent 32, r_0 6 LSTM
layers, style branches 4) and a smaller variant, under ``torch.inference_mode`` (and ``no_grad`` for contrast),
plus the end-to-end stream path (``StreamingStylizer.step``: checks + normalise + network + de-normalise +
rotation projection + velocity re-derivation). Every style branch advances on every frame (so a style change
mid-stream is instant), stacked into one batched matmul per layer. Frames are the corpus's own motions; weights
are the trained model's when ``--model-dir`` holds one, else random (latency does not depend on them).
(b) Training: ``train_erd`` on the corpus's train split at ``--steps`` (a fixed count; no time cap), reporting the
losses at the first and last history points, the content classifier's accuracy, wall time and steps/s.

The machine's load average is recorded next to the figures: on a shared 2-core box, p99 mostly measures the
scheduler. ``--quick``: a few hundred frames and steps, a smoke run.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.methods.erd import ErdTrainConfig, StreamingStylizer, load_erd, read_artifact, train_erd
from motionaug.augment.motion.features import compute_mean_std
from motionaug.models.style_erd import ErdNetwork, StyleErdConfig

SYNTH_STYLES = ("neutral", "angry", "childlike", "depressed", "old", "proud", "sneaky", "strutting")


def read_clips(corpus: Path, split: str | None) -> list[MotionClip]:
    """Clips of a corpus split, through whichever corpus door this checkout has."""
    try:
        from motionaug.augment.corpus import Corpus

        return list(Corpus(corpus, split=split))
    except ImportError:
        from motionaug.augment.corpus import open_corpus

        return list(open_corpus(corpus, split=split))


def percentiles(seconds: list[float]) -> dict[str, float]:
    ms = np.asarray(seconds) * 1e3
    return {"p50_ms": float(np.percentile(ms, 50)), "p99_ms": float(np.percentile(ms, 99)), "mean_ms": float(ms.mean())}


def random_network(clips: list[MotionClip], **sizes: Any) -> ErdNetwork:
    contents = sorted({c.content for c in clips if c.content}) or ["walk"]
    styles = sorted({c.style for c in clips if c.style and c.style != "neutral"}) or list(SYNTH_STYLES[1:])
    torch.manual_seed(0)
    net = ErdNetwork(StyleErdConfig(styles=("neutral", *styles), contents=tuple(contents), **sizes))
    norm = compute_mean_std(c.motion for c in clips)
    net.set_normalizer(torch.from_numpy(norm.mean), torch.from_numpy(norm.std))
    return net.eval()


def frame_source(clips: list[MotionClip], n: int) -> np.ndarray:
    frames = np.concatenate([c.motion for c in clips[:64]])
    reps = -(-n // len(frames))
    return np.tile(frames, (reps, 1))[:n]


def time_network_step(net: ErdNetwork, frames: np.ndarray, warmup: int, mode: str) -> dict[str, float]:
    x = net.normalize(torch.from_numpy(frames))
    src = net.style_onehot(torch.tensor([0]))
    con = net.content_onehot(torch.tensor([net.config.unknown_content]))
    tgt = net.mixture(net.config.styles[-1])[None]
    ctx = torch.inference_mode if mode == "inference_mode" else torch.no_grad
    times = []
    with ctx():
        state = net.initial_state(con)
        for i in range(warmup + len(frames)):
            xi = x[i % len(x)][None]
            start = time.perf_counter()
            _, state = net.step(xi, state, src, con, tgt)
            if i >= warmup:
                times.append(time.perf_counter() - start)
    return percentiles(times)


def time_stream(net: ErdNetwork, frames: np.ndarray, warmup: int) -> dict[str, float]:
    stylizer = StreamingStylizer(net, net.config.styles[-1])
    times = []
    for i in range(warmup + len(frames)):
        frame = frames[i % len(frames)]
        start = time.perf_counter()
        stylizer.step(frame)
        if i >= warmup:
            times.append(time.perf_counter() - start)
    return percentiles(times)


def bench_latency(clips: list[MotionClip], n_frames: int, model_dir: Path | None) -> dict[str, Any]:
    torch.set_num_threads(1)
    frames = frame_source(clips, n_frames)
    warmup = 300
    trained = model_dir is not None and (model_dir / "erd.json").is_file()
    paper = load_erd(model_dir) if trained else random_network(clips)
    small = random_network(clips, latent=16, neutral_layers=3, style_layers=2, dec_hidden=(64, 128))
    rows: dict[str, Any] = {}
    for name, net, mode in [
        ("step, paper sizes, inference_mode", paper, "inference_mode"),
        ("step, paper sizes, no_grad", paper, "no_grad"),
        ("step, small (latent 16, 3/2 layers), inference_mode", small, "inference_mode"),
    ]:
        rows[name] = time_network_step(net, frames, warmup, mode) | {"frames": len(frames)}
    rows["stream end-to-end (StreamingStylizer.step), paper sizes"] = time_stream(paper, frames, warmup) | {
        "frames": len(frames)
    }
    return {
        "weights": "trained" if trained else "random",
        "n_styles": paper.config.n_styles,
        "params": sum(p.numel() for p in paper.parameters()),
        "threads": 1,
        "loadavg": list(os.getloadavg()),
        "rows": rows,
    }


def bench_training(corpus: Path, out_dir: Path, config: ErdTrainConfig) -> dict[str, Any]:
    clips = read_clips(corpus, "train")
    last = {"t": time.perf_counter()}

    def progress(step: int, total: int, metrics: dict[str, float]) -> None:
        if step % 250 == 0 or step == total:
            now = time.perf_counter()
            shown = {k: round(v, 4) for k, v in metrics.items() if k in ("cls_loss", "gen", "rec", "adv", "per", "dis")}
            print(f"  step {step}/{total} ({now - last['t']:.1f}s) {shown}", flush=True)
            last["t"] = now

    load_before = list(os.getloadavg())
    start = time.perf_counter()
    path = train_erd(clips, out_dir, config, progress)
    seconds = time.perf_counter() - start
    art = read_artifact(path)
    return {
        "clips": len(clips),
        "steps": config.steps,
        "classifier_steps": config.classifier_steps,
        "batch_size": config.batch_size,
        "window_frames": art.data["window_frames"],
        "disc_window_frames": art.data["disc_window_frames"],
        "seconds": seconds,
        "steps_per_s": (config.steps + config.classifier_steps) / seconds,
        "classifier": art.classifier,
        "first": art.history[0],
        "last": art.history[-1],
        "loadavg_before": load_before,
        "loadavg_after": list(os.getloadavg()),
        "model_dir": str(path),
    }


def markdown(result: dict[str, Any]) -> str:
    lines = []
    if "latency" in result:
        lat = result["latency"]
        lines += [
            f"Latency, batch 1, 1 thread, {lat['weights']} weights, {lat['n_styles']} styles, "
            f"{lat['params']} params, load average {lat['loadavg'][0]:.1f}",
            "",
            "| path | frames | p50 ms | p99 ms | mean ms |",
            "|---|---:|---:|---:|---:|",
        ]
        for name, row in lat["rows"].items():
            lines.append(
                f"| {name} | {row['frames']} | {row['p50_ms']:.3f} | {row['p99_ms']:.3f} | {row['mean_ms']:.3f} |"
            )
        lines.append("")
    if "train" in result:
        tr = result["train"]
        lines += [
            f"Training: {tr['clips']} clips, {tr['classifier_steps']} classifier + {tr['steps']} GAN steps, "
            f"batch {tr['batch_size']}, window {tr['window_frames']} frames, critic window {tr['disc_window_frames']}: "
            f"{tr['seconds']:.0f} s ({tr['steps_per_s']:.2f} steps/s), content classifier accuracy "
            f"{tr['classifier']['accuracy']:.3f}",
            "",
            "| losses (mean over a history interval) | " + " | ".join(k for k in tr["last"] if k != "step") + " |",
            "|---|" + "---:|" * (len(tr["last"]) - 1),
        ]
        for label in ("first", "last"):
            row = tr[label]
            lines.append(
                f"| {label} (step {int(row['step'])}) | "
                + " | ".join(f"{v:.4f}" for k, v in row.items() if k != "step")
                + " |"
            )
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--corpus", type=Path, default=Path("/tmp/erd/synth"))
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--classifier-steps", type=int, default=300)
    parser.add_argument("--batch-size", type=int, default=32)
    parser.add_argument("--frames", type=int, default=3000)
    parser.add_argument("--model-dir", type=Path, default=Path("/tmp/erd/model"))
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--skip", default="", help="comma list of: latency, train")
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args(argv)
    skip = {s.strip() for s in args.skip.split(",") if s.strip()}
    if args.quick:
        args.steps, args.classifier_steps, args.frames = 20, 10, 500
    result: dict[str, Any] = {"python": platform.python_version(), "torch": torch.__version__, "cpus": os.cpu_count()}
    if "train" not in skip:
        config = ErdTrainConfig(steps=args.steps, classifier_steps=args.classifier_steps, batch_size=args.batch_size)
        print(f"training {config.steps} steps on {args.corpus} -> {args.model_dir}", flush=True)
        result["train"] = bench_training(args.corpus, args.model_dir, config)
    if "latency" not in skip:
        clips = read_clips(args.corpus, "test")
        result["latency"] = bench_latency(clips, args.frames, args.model_dir)
    print(markdown(result))
    if args.out:
        args.out.write_text(json.dumps(result, indent=1), encoding="utf-8")
    return result


if __name__ == "__main__":
    main()
