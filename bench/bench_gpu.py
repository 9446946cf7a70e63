"""GPU: the on-the-fly fine-tune's seconds per style and transfer clips/s at `paper` size, bf16 autocast.

Usage: python bench/bench_gpu.py [--pool 11700] [--pairs 8] [--frames 196] [--transfer-batch 64] [--json OUT]

Goal (issue 21): one style's fine-tune, `paper` MDM (d 512, 8 layers) with a HumanML3D-size L_s pool taken once
(the paper's Table 1 protocol: 3 min 10 s on an RTX 3090 Ti), in < 17 s on an H100-class GPU.

What runs per step is the fine-tune's compute (``augment.methods.onthefly.finetuning``): L_rec over the DDIM path
from K for the style pairs, L_s through the motion encoder for a pool batch, backward, clip, AdamW. It is written
out here on ``pick_device()`` with random weights and random motions (speed does not depend on either) and the
method's default parameters; steps = ceil(pool / batch size), one pass. Without CUDA it prints that it was
skipped and exits 0.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import time
from pathlib import Path

import torch

from motionaug.augment.device import bf16_autocast, pick_device
from motionaug.augment.diffusion import NoiseSchedule, bind_model, ddim_path, masked_mse, q_sample, start_step_for
from motionaug.augment.methods.onthefly import parse_params
from motionaug.models.mdm import MDM, MDMConfig
from motionaug.models.motion_encoder import MotionEncoder, MotionEncoderConfig, semantic_loss

FEATS, TEXT = 263, 512  # HumanML3D features; CLIP ViT-B/32 text width (the official prior's condition)


def path_end(model: MDM, x0: torch.Tensor, text: torch.Tensor, mask: torch.Tensor, steps: int, k: int) -> list:
    """The DDIM path from K of ``x0`` noised to K, as the fine-tune and the transfer run it."""
    sched = NoiseSchedule.cosine().respace(steps)
    t = torch.full((x0.shape[0],), k - 1, dtype=torch.long, device=x0.device)
    with bf16_autocast(None, x0.device):
        return ddim_path(bind_model(model, text, mask), q_sample(sched, x0, t, torch.randn_like(x0)), k, steps=steps)


def finetune_seconds(prior: MDM, encoder: MotionEncoder, args: argparse.Namespace, device: torch.device) -> dict:
    params = parse_params({})
    k = start_step_for(params.transfer_noise_step, params.ddim_steps)
    n_steps = math.ceil(args.pool / params.batch_size)
    optimizer = torch.optim.AdamW(prior.parameters(), lr=params.lr, weight_decay=0.0)
    shape = (args.pairs, args.frames, FEATS)
    styled, neutral = torch.randn(shape, device=device), torch.randn(shape, device=device)
    pair_text = torch.randn(args.pairs, TEXT, device=device)
    mask = torch.ones(shape[:2], dtype=torch.bool, device=device)
    pool_shape = (params.batch_size, args.frames, FEATS)
    timings = []
    for step in range(n_steps + args.warmup):
        torch.cuda.synchronize(device)
        start = time.perf_counter()
        preds = path_end(prior, neutral, pair_text, mask, params.ddim_steps, k)
        l_rec = torch.stack([masked_mse(p.float(), styled, mask).mean() for p in preds]).mean()
        pool, pool_text = torch.randn(pool_shape, device=device), torch.randn(params.batch_size, TEXT, device=device)
        pool_mask = torch.ones(pool_shape[:2], dtype=torch.bool, device=device)
        moved = path_end(prior, pool, pool_text, pool_mask, params.ddim_steps, k)[-1]
        with bf16_autocast(None, device):
            l_s = semantic_loss(encoder(moved, pool_mask).float(), pool_text)
        optimizer.zero_grad(set_to_none=True)
        (params.lambda_rec * l_rec + params.lambda_s * l_s).backward()
        torch.nn.utils.clip_grad_norm_(prior.parameters(), params.grad_clip or 1.0)
        optimizer.step()
        torch.cuda.synchronize(device)
        if step >= args.warmup:
            timings.append(time.perf_counter() - start)
    return {"finetune_s_per_style": sum(timings), "steps": n_steps, "s_per_step": sum(timings) / len(timings)}


@torch.no_grad()
def transfer_clips_per_s(prior: MDM, args: argparse.Namespace, device: torch.device) -> float:
    params = parse_params({})
    k = start_step_for(params.transfer_noise_step, params.ddim_steps)
    x = torch.randn(args.transfer_batch, args.frames, FEATS, device=device)
    text = torch.randn(args.transfer_batch, TEXT, device=device)
    mask = torch.ones(x.shape[:2], dtype=torch.bool, device=device)
    path_end(prior, x, text, mask, params.ddim_steps, k)  # warm-up
    torch.cuda.synchronize(device)
    start = time.perf_counter()
    for _ in range(args.repeats):
        path_end(prior, x, text, mask, params.ddim_steps, k)
    torch.cuda.synchronize(device)
    return args.repeats * args.transfer_batch / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pool", type=int, default=11700, help="L_s pool clips (HumanML3D train motions ~11.7k)")
    parser.add_argument("--pairs", type=int, default=8, help="style pairs per L_rec batch")
    parser.add_argument("--frames", type=int, default=196, help="frames per clip (HumanML3D's longest)")
    parser.add_argument("--transfer-batch", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = parser.parse_args()
    device = pick_device()
    if device.type != "cuda":
        print("bench_gpu: skipped: no CUDA device (torch.cuda.is_available() is False); no figure taken")
        return
    torch.manual_seed(0)
    prior = MDM(MDMConfig.named("paper", text_dim=TEXT)).to(device).eval()  # eval: as the fine-tune runs it
    # the base models' encoder reads through the base prior's input layer, not the copy being fine-tuned
    shared = copy.deepcopy(prior.input_process)
    encoder = MotionEncoder(MotionEncoderConfig.named("paper", text_dim=TEXT), shared).to(device).eval()
    encoder.requires_grad_(False)
    figures = {
        "device": torch.cuda.get_device_name(device),
        **finetune_seconds(prior, encoder, args, device),
        "transfer_clips_per_s": transfer_clips_per_s(prior, args, device),
        "args": vars(args) | {"json": str(args.json) if args.json else None},
    }
    print(json.dumps(figures, indent=2))
    if args.json is not None:
        args.json.write_text(json.dumps(figures, indent=2), encoding="utf-8")


if __name__ == "__main__":
    main()
