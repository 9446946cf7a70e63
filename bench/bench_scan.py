"""Forward+backward CPU time of the selective scan and the UMSD layers built on it, against a transformer layer.

Usage: python bench/bench_scan.py [--threads 2] [--batch 16] [--frames 196] [--width 256] [--d-state 16]
       [--expand 2] [--repeats 7] [--reference-repeats 3] [--out scan.json]

Rows (median, and best, of ``repeats`` timed runs after warm-up; the rows are timed round-robin, so load from other
tenants of a shared VM spreads over all of them rather than falling on one; targets are checked on medians):
- BiMamba layer (models/selective_scan.py) on (batch, frames, width);
- MSM block: our approximation of UMSD Eq. 7, built here (the paper gives no code): D0 = Lin(D_in) to the inner
  width, three iterations of D_r = IN(Phi+(mu(Lin(D))) + Phi-(mu(Lin(D)))), D = IN(Lin(D)) + D_r (the same Lin
  output in both places), D_res = D0 + D^3, and a last Lin back to ``width`` so the block maps width -> width;
  mu = causal depthwise conv (width 4) + SiLU, Phi+/Phi- = ``SelectiveSSM`` forward / backward, IN = InstanceNorm
  over time;
- torch.nn.TransformerEncoderLayer(width, 8 heads, 4 x width feed-forward, batch_first=True);
- the scan alone at the inner width (expand x width): ``selective_scan``, the sequential loop
  ``selective_scan_reference`` under autograd, and mambapy's Blelloch ``pscan`` (through its own
  ``MambaBlock.selective_scan``; skipped with a note when mambapy is not installed).
Each row also gets a forward-only (no-grad) time, the cost in diffusion sampling.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from collections.abc import Callable

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from motionaug.models.selective_scan import (
    BiMamba,
    SelectiveSSM,
    causal_conv1d,
    selective_scan,
    selective_scan_reference,
)


class MSMBlock(nn.Module):
    """Our reading of UMSD Eq. 7 (see the module docstring); (B, L, width) -> (B, L, width)."""

    def __init__(self, width: int, expand: int = 2, d_state: int = 16, d_conv: int = 4, iterations: int = 3) -> None:
        super().__init__()
        inner = expand * width
        self.lin_in = nn.Linear(width, inner)
        self.lins = nn.ModuleList(nn.Linear(inner, inner) for _ in range(iterations))
        self.convs = nn.ModuleList(nn.Conv1d(inner, inner, d_conv, groups=inner) for _ in range(iterations))
        self.forward_ssms = nn.ModuleList(SelectiveSSM(inner, d_state) for _ in range(iterations))
        self.backward_ssms = nn.ModuleList(SelectiveSSM(inner, d_state, reverse=True) for _ in range(iterations))
        self.lin_out = nn.Linear(inner, width)

    def forward(self, x: Tensor) -> Tensor:
        d0 = self.lin_in(x)
        d = d0
        for lin, conv, phi_plus, phi_minus in zip(self.lins, self.convs, self.forward_ssms, self.backward_ssms):
            p = lin(d)
            mu = F.silu(causal_conv1d(conv, p, anticausal=False))
            d = instance_norm(p) + instance_norm(phi_plus(mu) + phi_minus(mu))
        return self.lin_out(d0 + d)


def instance_norm(x: Tensor) -> Tensor:
    """InstanceNorm1d (no affine) over time, per sample and channel, on (B, L, C)."""
    return F.instance_norm(x.transpose(1, 2)).transpose(1, 2)


def mambapy_scan() -> Callable[..., Tensor] | None:
    """mambapy's selective scan (pscan inside), on its (B, L, ED) layout, or None when mambapy is absent."""
    try:
        from mambapy.mamba import MambaBlock
    except ImportError:
        return None
    return lambda x, delta, A, B, C, D: MambaBlock.selective_scan(None, x, delta, A, B, C, D)


def layer_case(module: nn.Module, x: Tensor) -> tuple[Callable[[], None], Callable[[], None]]:
    """(forward+backward, forward-only) closures for a module on input x."""
    weight = torch.randn_like(module(x))

    def train_step() -> None:
        module.zero_grad(set_to_none=True)
        x.grad = None
        (module(x) * weight).sum().backward()

    def forward() -> None:
        with torch.no_grad():
            module(x)

    return train_step, forward


def scan_case(fn: Callable[..., Tensor], inputs: list[Tensor]) -> tuple[Callable[[], None], Callable[[], None]]:
    weight = torch.randn_like(fn(*inputs))

    def train_step() -> None:
        for t in inputs:
            t.grad = None
        (fn(*inputs) * weight).sum().backward()

    def forward() -> None:
        with torch.no_grad():
            fn(*inputs)

    return train_step, forward


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--frames", type=int, default=196)
    parser.add_argument("--width", type=int, default=256)
    parser.add_argument("--d-state", type=int, default=16)
    parser.add_argument("--expand", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=7, help="timed runs per row (median)")
    parser.add_argument("--reference-repeats", type=int, default=3, help="timed runs of the slow sequential loop")
    parser.add_argument("--warmup", type=int, default=2)
    parser.add_argument("--out", help="write the results as JSON here")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    b, length, width, n = args.batch, args.frames, args.width, args.d_state
    inner = args.expand * width

    x = torch.randn(b, length, width, requires_grad=True)
    cases: dict[str, tuple[Callable[[], None], Callable[[], None]]] = {
        "BiMamba layer": layer_case(BiMamba(width, d_state=n, expand=args.expand), x),
        "MSM block (Eq. 7 approx.)": layer_case(MSMBlock(width, args.expand, n), x),
        "TransformerEncoderLayer": layer_case(
            nn.TransformerEncoderLayer(d_model=width, nhead=8, dim_feedforward=4 * width, batch_first=True), x
        ),
    }
    # The scan alone, on mamba-ssm's layout (B, D, L) / (B, N, L); delta already positive (no softplus), no gate.
    u, B, C = torch.randn(b, inner, length), torch.randn(b, n, length), torch.randn(b, n, length)
    delta = F.softplus(torch.randn(b, inner, length) - 3)
    A = -torch.arange(1, n + 1, dtype=torch.float32).repeat(inner, 1)
    D = torch.ones(inner)
    ours = [t.clone().requires_grad_() for t in (u, delta, A, B, C, D)]
    cases["scan: selective_scan (ours)"] = scan_case(lambda *t: selective_scan(*t, delta_softplus=False), ours)
    loop = [t.clone().requires_grad_() for t in (u, delta, A, B, C, D)]
    cases["scan: sequential loop + autograd"] = scan_case(
        lambda *t: selective_scan_reference(*t, delta_softplus=False), loop
    )
    pscan = mambapy_scan()
    if pscan is None:
        print("mambapy is not importable: its pscan row is skipped (pip install mambapy)")
    else:
        native = [t.transpose(1, 2).contiguous() if t.dim() == 3 else t for t in (u, delta, A, B, C, D)]
        cases["scan: mambapy pscan"] = scan_case(pscan, [t.requires_grad_() for t in native])

    load_before = os.getloadavg()
    runs: dict[str, dict[str, list[float]]] = {name: {"fwd_bwd": [], "fwd": []} for name in cases}
    for _ in range(args.warmup):
        for train_step, forward in cases.values():
            train_step()
            forward()
    for r in range(args.repeats):
        for name, (train_step, forward) in cases.items():
            if "sequential" in name and r >= args.reference_repeats:
                continue
            for kind, fn in (("fwd_bwd", train_step), ("fwd", forward)):
                start = time.perf_counter()
                fn()
                runs[name][kind].append(time.perf_counter() - start)
    load_after = os.getloadavg()

    median = {name: {k: statistics.median(v) for k, v in r.items()} for name, r in runs.items()}
    best = {name: {k: min(v) for k, v in r.items()} for name, r in runs.items()}
    transformer = median["TransformerEncoderLayer"]["fwd_bwd"]
    scan = median["scan: selective_scan (ours)"]["fwd_bwd"]
    print(
        f"\nbatch {b} x {length} frames, width {width} (inner {inner}), d_state {n}, {args.threads} threads, "
        f"median of {args.repeats} (loop: {args.reference_repeats}); load average {load_before[0]:.1f} -> "
        f"{load_after[0]:.1f}\n"
    )
    print("| row | fwd+bwd, median (ms) | x transformer | fwd+bwd, best (ms) | fwd only, no grad, median (ms) |")
    print("|---|---|---|---|---|")
    for name, m in median.items():
        cells = [f"{m['fwd_bwd'] * 1e3:.1f}", f"{m['fwd_bwd'] / transformer:.2f}"]
        cells += [f"{best[name]['fwd_bwd'] * 1e3:.1f}", f"{m['fwd'] * 1e3:.1f}"]
        print(f"| {name} | {' | '.join(cells)} |")

    targets = {
        "BiMamba layer <= 2x transformer": median["BiMamba layer"]["fwd_bwd"] <= 2 * transformer,
        "MSM block <= 6x transformer": median["MSM block (Eq. 7 approx.)"]["fwd_bwd"] <= 6 * transformer,
        "scan faster than the sequential loop": scan < median["scan: sequential loop + autograd"]["fwd_bwd"],
    }
    if "scan: mambapy pscan" in median:
        targets["scan faster than mambapy pscan"] = scan < median["scan: mambapy pscan"]["fwd_bwd"]
    print()
    for what, met in targets.items():
        print(f"- {what}: {'met' if met else 'MISSED'}")

    if args.out:
        with open(args.out, "w", encoding="utf-8") as f:
            json.dump(
                {
                    "config": vars(args) | {"inner": inner},
                    "machine": {
                        "processor": platform.processor() or platform.machine(),
                        "cpus": os.cpu_count(),
                        "torch": torch.__version__,
                        "load_average_before_after": [load_before[0], load_after[0]],
                    },
                    "median_seconds": median,
                    "best_seconds": best,
                    "runs_seconds": runs,
                    "targets_met": targets,
                },
                f,
                indent=2,
            )


if __name__ == "__main__":
    main()
