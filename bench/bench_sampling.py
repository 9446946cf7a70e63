"""DDIM sampling throughput of the MDM denoiser on CPU, fp32 and bf16 autocast, against a measured matmul ceiling.

Usage: python bench/bench_sampling.py [--config paper] [--batch 16] [--frames 196] [--steps 20] [--threads 2]
       [--repeats 1] [--ragged] [--guidance 2.5]
Reports clips/s and achieved GFLOP/s (analytic FLOPs of the network, see ``forward_flops``) next to the GFLOP/s
of a 2048x2048 matmul in the same dtype on the same threads (FLOPs count padded frames too). Weights are random:
speed does not depend on them.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable

import torch

from motionaug.augment.diffusion import bind_model, ddim_sample
from motionaug.models.mdm import MDM, MDMConfig


def best_seconds(
    fn: Callable[[], object], repeats: int, warmup: Callable[[], object] | None = None
) -> tuple[float, float]:
    """(wall, process CPU) seconds of the fastest of ``repeats`` calls after a warm-up call.

    On shared cores the fastest run is the least disturbed one; CPU / (wall x threads) near 1 says it was not.
    """
    (warmup or fn)()
    runs = []
    for _ in range(repeats):
        wall, cpu = time.perf_counter(), time.process_time()
        fn()
        runs.append((time.perf_counter() - wall, time.process_time() - cpu))
    return min(runs)


def matmul_gflops(dtype: torch.dtype, n: int = 2048, repeats: int = 5) -> float:
    """Achieved GFLOP/s of an n x n @ n x n matmul (2 n^3 FLOPs): the practical ceiling for this dtype."""
    a, b = torch.randn(n, n).to(dtype), torch.randn(n, n).to(dtype)
    return 2 * n**3 / best_seconds(lambda: a @ b, repeats)[0] / 1e9


def forward_flops(config: MDMConfig, batch: int, frames: int) -> float:
    """Multiply-add FLOPs (x2) of one forward: projections, attention scores/mixing, feed-forward, in/out layers."""
    d, ff, seq = config.latent_dim, config.ff_size, frames + 1
    tokens = batch * seq
    per_layer = 2 * tokens * d * (3 * d + d + 2 * ff) + 2 * 2 * batch * seq * seq * d
    io = 2 * batch * frames * config.n_feats * d * 2 + 2 * batch * d * (2 * d + config.text_dim)
    return config.num_layers * per_layer + io


def sample_seconds(
    model: MDM, batch: int, frames: int, steps: int, bf16: bool, guidance: float | None, repeats: int, ragged: bool
) -> tuple[float, float]:
    """(wall, CPU) seconds of one DDIM sampling call (no grad), optionally under bf16 autocast.

    ``ragged``: the second half of the batch is half as long (padded), which exercises the masked attention path.
    """
    text = torch.randn(batch, model.config.text_dim)
    mask = torch.ones(batch, frames, dtype=torch.bool)
    if ragged:
        mask[batch // 2 :, frames // 2 :] = False
    model_fn = bind_model(model, text, mask)
    shape = (batch, frames, model.config.n_feats)

    def run() -> torch.Tensor:
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
            return ddim_sample(
                model_fn, shape, steps=steps, guidance_scale=guidance, generator=torch.Generator().manual_seed(0)
            )

    def one_forward() -> torch.Tensor:
        with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
            return model_fn(torch.randn(shape), torch.zeros(batch, dtype=torch.long))

    return best_seconds(run, repeats, warmup=one_forward)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="paper")
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--frames", type=int, default=196)
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--ragged", action="store_true", help="pad half of the batch to half length")
    parser.add_argument(
        "--guidance", type=float, default=None, help="classifier-free guidance scale (2 forwards per step)"
    )
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    config = MDMConfig.named(args.config)
    model = MDM(config).eval()
    calls = args.steps * (1 if args.guidance is None else 2)
    flops = forward_flops(config, args.batch, args.frames) * calls
    report: dict[str, object] = {
        "config": args.config,
        "batch": args.batch,
        "frames": args.frames,
        "steps": args.steps,
        "threads": args.threads,
        "guidance": args.guidance,
        "ragged": args.ragged,
        "gflop_per_sample_call": flops / 1e9,
    }
    for name, dtype, bf16 in (("fp32", torch.float32, False), ("bf16", torch.bfloat16, True)):
        ceiling = matmul_gflops(dtype)
        seconds, cpu = sample_seconds(
            model, args.batch, args.frames, args.steps, bf16, args.guidance, args.repeats, args.ragged
        )
        achieved = flops / seconds / 1e9
        report[name] = {
            "seconds": round(seconds, 3),
            "clips_per_s": round(args.batch / seconds, 3),
            "gflops": round(achieved, 1),
            "matmul_ceiling_gflops": round(ceiling, 1),
            "fraction_of_ceiling": round(achieved / ceiling, 3),
            "cpu_utilisation": round(cpu / (seconds * args.threads), 2),
        }
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
