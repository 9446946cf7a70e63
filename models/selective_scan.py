"""Selective scan (Mamba's S6, Gu & Dao 2023) for CPU in plain PyTorch, and the Mamba mixers built on it.

UMSD's Motion Style Mamba denoiser (Qian et al., ACM MM 2025, Sec. 3.3) sums a forward and a backward SSM over the
same causal-conv features (Eq. 7); this module gives the scan, ``MambaLayer`` and ``BiMamba``. Recurrence (Alg. 2):
``h_t = exp(delta_t A) h_{t-1} + delta_t B_t u_t``, ``y_t = <C_t, h_t> + D u_t``. Why this design: A is diagonal, so
Mamba-2's chunk matmuls do not apply, and the log-space chunk form overflows float32 over long decays. Here a chunk
does its decays, inputs, read-outs and gradient reductions as batched ops and only the state update is sequential;
the only exponentials are exp(delta A) <= 1, so nothing overflows. The backward re-runs each chunk from its saved
entering state (memory O(B D N L / chunk), like the CUDA kernel); channels are split across threads (``_ScanWorkers``).
"""

from __future__ import annotations

import functools
import math
import os
import threading
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import torch
import torch.nn.functional as F
from torch import Tensor, nn

__all__ = ["BiMamba", "MambaLayer", "SelectiveSSM", "causal_conv1d", "selective_scan", "selective_scan_reference"]

# Elements of one chunk's (chunk, B, N, channel group) work buffer: the backward keeps three per worker, which should
# stay in the shared L3 cache (2 MiB each in float32) rather than go out to memory between the steps of a chunk.
_CHUNK_ELEMENTS = 1 << 19
# Fewest state elements (B * N * group channels) worth a worker thread of their own.
_MIN_GROUP_ELEMENTS = 1 << 15
_LOG2E = math.log2(math.e)
_T, _R = TypeVar("_T"), TypeVar("_R")


def _prepare(
    u: Tensor, delta: Tensor, delta_bias: Tensor | None, delta_softplus: bool, mask: Tensor | None
) -> tuple[Tensor, Tensor, Tensor | None]:
    """delta' = softplus(delta + bias) as in mamba-ssm; padded steps get delta' = 0 and u = 0 (a pass-through step)."""
    if delta_bias is not None:
        delta = delta + delta_bias[..., None].to(delta.dtype)
    if delta_softplus:
        delta = F.softplus(delta)
    keep = None
    if mask is not None:
        keep = mask[:, None, :].to(u.dtype)  # (B, 1, L)
        delta, u = delta * keep, u * keep
    return u, delta, keep


def _finish(y: Tensor, u: Tensor, D: Tensor | None, z: Tensor | None, keep: Tensor | None) -> Tensor:
    """y + D u, gated by silu(z) (Gu & Dao 2023, Fig. 3), zero at padded steps."""
    if D is not None:
        y = y + D[:, None].to(y.dtype) * u
    if z is not None:
        y = y * F.silu(z)
    if keep is not None:
        y = y * keep
    return y


def selective_scan_reference(
    u: Tensor,
    delta: Tensor,
    A: Tensor,
    B: Tensor,
    C: Tensor,
    D: Tensor | None = None,
    z: Tensor | None = None,
    delta_bias: Tensor | None = None,
    delta_softplus: bool = True,
    mask: Tensor | None = None,
    reverse: bool = False,
) -> Tensor:
    """The plain sequential recurrence, one step at a time: the ground truth for ``selective_scan``.

    Written independently of the fast path's conventions: padded steps are skipped (the state is carried over by
    ``torch.where``) rather than zeroed, and ``reverse`` walks the time indices backwards rather than flipping.
    """
    if delta_bias is not None:
        delta = delta + delta_bias[..., None].to(delta.dtype)
    if delta_softplus:
        delta = F.softplus(delta)
    batch, channels, length = u.shape
    h = u.new_zeros(batch, channels, A.shape[1])
    ys: list[Tensor] = [u.new_zeros(batch, channels)] * length
    for t in range(length - 1, -1, -1) if reverse else range(length):
        dt = delta[:, :, t, None]
        h_new = torch.exp(dt * A) * h + dt * B[:, None, :, t] * u[:, :, t, None]
        if mask is not None:
            h_new = torch.where(mask[:, t, None, None], h_new, h)
        h = h_new
        y = (h * C[:, None, :, t]).sum(-1)
        if D is not None:
            y = y + D * u[:, :, t]
        if z is not None:
            y = y * F.silu(z[:, :, t])
        if mask is not None:
            y = torch.where(mask[:, t, None], y, torch.zeros_like(y))
        ys[t] = y
    return torch.stack(ys, dim=-1)


@functools.cache
def _cuda_kernel() -> Callable[..., Tensor] | None:
    """mamba-ssm's fused CUDA selective scan when it is installed and importable; never required."""
    try:
        from mamba_ssm.ops.selective_scan_interface import selective_scan_fn
    except Exception:  # ImportError, or a broken CUDA extension build
        return None
    return selective_scan_fn


def selective_scan(
    u: Tensor,
    delta: Tensor,
    A: Tensor,
    B: Tensor,
    C: Tensor,
    D: Tensor | None = None,
    z: Tensor | None = None,
    delta_bias: Tensor | None = None,
    delta_softplus: bool = True,
    mask: Tensor | None = None,
    reverse: bool = False,
    *,
    chunk_size: int | None = None,
    workers: int | None = None,
) -> Tensor:
    """Selective scan with mamba-ssm's ``selective_scan_fn`` shapes: u, delta, z (B, D, L); A (D, N); B, C (B, N, L);
    D, delta_bias (D,). Returns y (B, D, L).

    mask (B, L) bool, True = a real frame: padded steps have delta = 0 and u = 0, so the state passes through them
    unchanged (in either direction) and they contribute nothing; their outputs are 0. For trailing padding, the
    valid part equals the scan of the unpadded sequence in both directions.
    reverse: scan from the last step to the first (the backward SSM Phi- of UMSD Eq. 7).
    chunk_size: steps per chunk (default: sized so that a chunk's work buffer is about 2 MiB in float32).
    workers: threads, each scanning a slice of the channels (default: ``torch.get_num_threads()``, fewer for a
    small state).
    """
    if u.is_cuda and _cuda_kernel() is not None:
        return _selective_scan_cuda(u, delta, A, B, C, D, z, delta_bias, delta_softplus, mask, reverse)
    u, delta, keep = _prepare(u, delta, delta_bias, delta_softplus, mask)
    compute = torch.float32 if u.dtype in (torch.float16, torch.bfloat16) else u.dtype
    batch, channels, _ = u.shape
    if workers is None:  # one per intra-op thread, but no group so small that per-op overhead dominates
        workers = torch.get_num_threads() if u.device.type == "cpu" else 1
        workers = min(workers, batch * channels * A.shape[1] // _MIN_GROUP_ELEMENTS)
    workers = max(1, min(channels, workers))
    if chunk_size is None:
        group = -(-channels // workers)
        chunk_size = max(1, min(64, _CHUNK_ELEMENTS // max(1, batch * group * A.shape[1])))
    delta_c, u_c, A_c, B_c, C_c = (t.to(compute) for t in (delta, u, A, B, C))
    y = _ChunkedScan.apply(delta_c, delta_c * u_c, A_c, B_c, C_c, chunk_size, reverse, workers).to(u.dtype)
    return _finish(y, u, D, z, keep)


def _selective_scan_cuda(
    u: Tensor,
    delta: Tensor,
    A: Tensor,
    B: Tensor,
    C: Tensor,
    D: Tensor | None,
    z: Tensor | None,
    delta_bias: Tensor | None,
    delta_softplus: bool,
    mask: Tensor | None,
    reverse: bool,
) -> Tensor:
    """mamba-ssm's kernel, with our mask (zeroed delta and u) and direction (flipped time) applied around it."""
    kernel = _cuda_kernel()
    assert kernel is not None
    if mask is None and not reverse:
        return kernel(u, delta, A, B, C, D, z, delta_bias, delta_softplus)
    u, delta, keep = _prepare(u, delta, delta_bias, delta_softplus, mask)
    flip = (lambda t: t.flip(-1)) if reverse else (lambda t: t)
    y = flip(kernel(flip(u), flip(delta), A, flip(B), flip(C), None, None, None, False))
    return _finish(y, u, D, z, keep)


class _ChunkedScan(torch.autograd.Function):
    """y_t = <C_t, h_t>, h_t = exp(delta_t A) h_{t-1} + x_t B_t with x = delta * u, and its exact gradient.

    Channels are independent in this recurrence (only B and C are shared), so the channels are split into one
    contiguous group per worker thread (as the CUDA kernel splits them over thread blocks); see ``_scan_forward`` and
    ``_scan_backward`` for the per-group work and ``_ScanWorkers`` for why threads.
    """

    @staticmethod
    def forward(
        ctx, delta: Tensor, x: Tensor, A: Tensor, B: Tensor, C: Tensor, chunk: int, reverse: bool, workers: int
    ) -> Tensor:
        BT, CT = _time_major(B, reverse), _time_major(C, reverse)  # (L, B, N), shared read-only by every group
        groups = _channel_groups(delta.shape[1], workers)

        def run(group: slice) -> tuple[Tensor, list[Tensor]]:
            dT, xT = _time_major(delta[:, group], reverse), _time_major(x[:, group], reverse)  # (L, B, Dg)
            At = A[group].t().contiguous()  # (N, Dg)
            y, starts = _scan_forward(dT, xT, At, BT, CT, chunk)
            return y, [dT, xT, At, starts]

        results = _ScanWorkers.map(run, groups)
        ctx.chunk, ctx.reverse, ctx.groups = chunk, reverse, groups
        ctx.channels_inner = tuple(t.stride(1) == 1 for t in (delta, x, B, C))
        ctx.save_for_backward(BT, CT, *(t for _, saved in results for t in saved))
        y = _cat([y for y, _ in results], dim=2)
        return _batch_major(y, reverse, channels_inner=x.stride(1) == 1)

    @staticmethod
    def backward(ctx, grad_y: Tensor) -> tuple[Tensor | None, ...]:
        BT, CT, *saved = ctx.saved_tensors
        chunk, reverse, groups = ctx.chunk, ctx.reverse, ctx.groups
        gT = _time_major(grad_y, reverse)

        def run(i: int) -> tuple[Tensor, ...]:
            dT, xT, At, starts = saved[4 * i : 4 * i + 4]
            return _scan_backward(dT, xT, At, BT, CT, starts, gT[:, :, groups[i]].contiguous(), chunk)

        parts = _ScanWorkers.map(run, range(len(groups)))
        d_delta, d_x, d_At = (_cat([p[i] for p in parts], dim=-1) for i in range(3))
        d_B, d_C = (functools.reduce(torch.add, [p[i] for p in parts]) for i in (3, 4))  # sums over all channels
        layouts = dict(zip(("delta", "x", "B", "C"), ctx.channels_inner, strict=True))
        return (
            _batch_major(d_delta, reverse, layouts["delta"]),
            _batch_major(d_x, reverse, layouts["x"]),
            d_At.t(),
            _batch_major(d_B, reverse, layouts["B"]),
            _batch_major(d_C, reverse, layouts["C"]),
            None,
            None,
            None,
        )


def _scan_forward(dT: Tensor, xT: Tensor, At: Tensor, BT: Tensor, CT: Tensor, chunk: int) -> tuple[Tensor, Tensor]:
    """One channel group, time-major: dT, xT (L, B, D); At = A^T (N, D); BT, CT (L, B, N) -> y (L, B, D) and the
    state entering each chunk (n_chunks, B, N, D), all the backward needs to recompute the states.

    The state is laid out (B, N, D) so that sums over N add whole rows of D and sums over D are long contiguous
    dot products. Per chunk [t0, t1): decays and inputs are made for the whole chunk at once, the state advances
    with one in-place multiply-add per step (into the input buffer, which becomes the chunk's states), and y is
    one batched matmul over the chunk.
    """
    length, batch, channels = dT.shape
    n_state = At.shape[0]
    At2 = At * _LOG2E
    n_chunks = -(-length // chunk)
    starts = dT.new_empty(n_chunks, batch, n_state, channels)
    starts[0].zero_()
    y = dT.new_empty(length, batch, channels)
    a = dT.new_empty(chunk, batch, n_state, channels)
    h = dT.new_empty(chunk + 1, batch, n_state, channels)  # h[0] = the state entering the chunk
    for c in range(n_chunks):
        t0, t1 = c * chunk, min(length, (c + 1) * chunk)
        k, rows = t1 - t0, (t1 - t0) * batch
        states = _chunk_states(dT[t0:t1], xT[t0:t1], At2, BT[t0:t1], starts[c], a[:k], h[: k + 1])
        y_rows = y[t0:t1].view(rows, 1, channels)
        torch.bmm(CT[t0:t1].view(rows, 1, n_state), states.view(rows, n_state, channels), out=y_rows)
        if c + 1 < n_chunks:
            starts[c + 1].copy_(states[-1])
    return y, starts


def _scan_backward(
    dT: Tensor, xT: Tensor, At: Tensor, BT: Tensor, CT: Tensor, starts: Tensor, gT: Tensor, chunk: int
) -> tuple[Tensor, ...]:
    """Gradients for one channel group: (d_delta, d_x) (L, B, D), d_At (N, D), (d_B, d_C) (L, B, N).

    Walks the chunks from the last (the recompute strategy of Gu & Dao 2023, Sec. 3.3.2): recomputes the chunk's
    states from the saved state entering it, runs the adjoint recurrence dh_t = C_t g_t + a_{t+1} dh_{t+1} one
    multiply-add per step, and reduces every gradient with batched ops over the chunk:

        dC_t = sum_d g_t h_t     dx_t = sum_n dh_t B_t     dB_t = sum_d dh_t x_t
        W_t = dh_t h_{t-1} a_t:  ddelta_t = sum_n W_t A,   dA = sum_{b,t} W_t delta_t.
    """
    length, batch, channels = dT.shape
    n_chunks, n_state = starts.shape[0], At.shape[0]
    At2 = At * _LOG2E
    # Two (a, dh) buffers, used by alternate chunks: the adjoint of a chunk's last step reads the first step of the
    # chunk after it (processed just before), which is still in the other buffer.
    a_bufs = gT.new_empty(2, chunk, batch, n_state, channels)
    dh_bufs = gT.new_empty(2, chunk, batch, n_state, channels)
    h = gT.new_empty(chunk + 1, batch, n_state, channels)
    d_delta, d_x = gT.new_empty(length, batch, channels), gT.new_empty(length, batch, channels)
    d_B, d_C = gT.new_empty(length, batch, n_state), gT.new_empty(length, batch, n_state)
    d_At = gT.new_zeros(n_state, channels)
    for c in range(n_chunks - 1, -1, -1):
        t0, t1 = c * chunk, min(length, (c + 1) * chunk)
        k, rows = t1 - t0, (t1 - t0) * batch
        a, a_after, dh_after = a_bufs[c % 2], a_bufs[(c + 1) % 2][0], dh_bufs[(c + 1) % 2][0]
        states = _chunk_states(dT[t0:t1], xT[t0:t1], At2, BT[t0:t1], starts[c], a[:k], h[: k + 1])
        # Adjoint recurrence, backwards through the chunk; the step after it is the next chunk's first.
        adj = torch.mul(gT[t0:t1, :, None, :], CT[t0:t1, :, :, None], out=dh_bufs[c % 2][:k])
        if c + 1 < n_chunks:
            adj[k - 1].addcmul_(a_after, dh_after)
        for j in range(k - 2, -1, -1):
            adj[j].addcmul_(a[j + 1], adj[j + 1])
        adj_rows, state_rows = adj.view(rows, n_state, channels), states.view(rows, n_state, channels)
        # Sums over D as (rows, 1, D) @ (rows, D, N): far faster on CPU than (rows, N, D) @ (rows, D, 1).
        torch.bmm(gT[t0:t1].view(rows, 1, channels), state_rows.transpose(1, 2), out=d_C[t0:t1].view(rows, 1, n_state))
        torch.bmm(xT[t0:t1].view(rows, 1, channels), adj_rows.transpose(1, 2), out=d_B[t0:t1].view(rows, 1, n_state))
        torch.bmm(BT[t0:t1].view(rows, 1, n_state), adj_rows, out=d_x[t0:t1].view(rows, 1, channels))
        w = h[:k].mul_(adj).mul_(a[:k])  # W_t = dh_t h_{t-1} a_t, in place of h_{t-1}
        torch.sum(w * At, dim=2, out=d_delta[t0:t1])
        d_At += w.mul_(dT[t0:t1, :, None, :]).sum(dim=(0, 1))
    return d_delta, d_x, d_At, d_B, d_C


def _channel_groups(channels: int, workers: int) -> list[slice]:
    """Split [0, channels) into at most ``workers`` contiguous, near-equal slices."""
    n = max(1, min(workers, channels))
    bounds = [round(i * channels / n) for i in range(n + 1)]
    return [slice(lo, hi) for lo, hi in zip(bounds[:-1], bounds[1:], strict=True)]


class _ScanWorkers:
    """A process-wide pool of threads, each with one intra-op thread, that run the channel groups of a scan.

    Why threads: a scan is thousands of small ops (a few per time step). Run with PyTorch's intra-op OpenMP threads,
    every one of them ends in a barrier, and on a shared VM one descheduled thread stalls them all, so a 2-thread
    scan can be far slower than a 1-thread one. Independent channel groups on single-threaded workers need one join
    per call. Setting a worker to one thread (``torch.set_num_threads`` from inside it) also writes PyTorch's
    process-wide default, so that is restored once the workers are up.
    """

    _lock = threading.Lock()
    _pool: ThreadPoolExecutor | None = None
    _size, _pid = 0, 0

    @classmethod
    def map(cls, fn: Callable[[_T], _R], items: Iterable[_T]) -> list[_R]:
        """[fn(item) for item in items], run with autograd off (grad mode is per thread), on the pool when > 1."""

        def no_grad_fn(item: _T) -> _R:
            with torch.no_grad():
                return fn(item)

        items = list(items)
        if len(items) == 1:
            return [no_grad_fn(items[0])]
        pool = cls._get(len(items))
        return [future.result() for future in [pool.submit(no_grad_fn, item) for item in items]]

    @classmethod
    def _get(cls, size: int) -> ThreadPoolExecutor:
        with cls._lock:
            if cls._pool is None or cls._size < size or cls._pid != os.getpid():  # threads do not survive a fork
                caller_threads = torch.get_num_threads()
                ready = threading.Barrier(size + 1)

                def single_threaded() -> None:
                    torch.set_num_threads(1)
                    ready.wait()

                pool = ThreadPoolExecutor(size, thread_name_prefix="selective-scan")
                for _ in range(size):  # each blocks on the barrier, so each lands on its own new thread
                    pool.submit(single_threaded)
                ready.wait()
                torch.set_num_threads(caller_threads)
                # A smaller pool being replaced is just dropped: its threads exit once it is garbage, after any
                # work another caller still has on it.
                cls._pool, cls._size, cls._pid = pool, size, os.getpid()
            return cls._pool


def _time_major(t: Tensor, reverse: bool) -> Tensor:
    """(B, X, L) -> contiguous (L, B, X), in scan order."""
    t = t.permute(2, 0, 1)
    if reverse:  # one copy (flip would keep the permuted strides)
        return t.index_select(0, torch.arange(t.shape[0] - 1, -1, -1, device=t.device))
    return t.contiguous()


def _batch_major(t: Tensor, reverse: bool, channels_inner: bool) -> Tensor:
    """Inverse of ``_time_major``: (L, B, X) -> (B, X, L), in the memory layout of the matching input, so the
    elementwise ops around the scan see one layout: a view when X is innermost there (as for activations from a
    Linear), else a (B, X, L)-contiguous copy."""
    t = (t.flip(0) if reverse else t).permute(1, 2, 0)
    return t if channels_inner else t.contiguous()


def _cat(parts: list[Tensor], dim: int) -> Tensor:
    return parts[0] if len(parts) == 1 else torch.cat(parts, dim=dim)


def _chunk_states(delta: Tensor, x: Tensor, At2: Tensor, B: Tensor, start: Tensor, a: Tensor, h: Tensor) -> Tensor:
    """Fills a = exp(delta A) = exp2(delta A log2 e) and h[1:] = the chunk's states (h[0] = start); returns h[1:].

    delta, x (k, B, D); At2 = A^T log2(e) (N, D); B (k, B, N); a (k, B, N, D); h (k + 1, B, N, D).
    Each step is one in-place h_t = a_t h_{t-1} + x_t B_t over the whole state.
    """
    torch.mul(delta[:, :, None, :], At2, out=a).exp2_()
    torch.mul(x[:, :, None, :], B[:, :, :, None], out=h[1:])
    h[0].copy_(start)
    for j in range(a.shape[0]):
        h[j + 1].addcmul_(a[j], h[j])
    return h[1:]


class SelectiveSSM(nn.Module):
    """The input-dependent SSM of a Mamba block: x_proj -> (dt, B, C), dt_proj, A_log, D (Gu & Dao 2023, Alg. 2).

    (B, L, d_inner) -> (B, L, d_inner), optionally gated by silu(z). One of these is Phi+ or Phi- in UMSD Eq. 7.
    Initialisation follows mamba-ssm: A = -[1..N] per channel (S4D-real), dt log-uniform in [dt_min, dt_max] through
    the inverse softplus in dt_proj's bias, D = 1.
    """

    def __init__(
        self,
        d_inner: int,
        d_state: int = 16,
        dt_rank: int | None = None,
        reverse: bool = False,
        dt_min: float = 1e-3,
        dt_max: float = 0.1,
        dt_init_floor: float = 1e-4,
    ) -> None:
        super().__init__()
        self.d_state, self.reverse = d_state, reverse
        self.dt_rank = dt_rank if dt_rank is not None else math.ceil(d_inner / 32)
        self.x_proj = nn.Linear(d_inner, self.dt_rank + 2 * d_state, bias=False)
        self.dt_proj = nn.Linear(self.dt_rank, d_inner, bias=True)
        nn.init.uniform_(self.dt_proj.weight, -(self.dt_rank**-0.5), self.dt_rank**-0.5)
        dt = torch.exp(torch.rand(d_inner) * (math.log(dt_max) - math.log(dt_min)) + math.log(dt_min))
        dt = dt.clamp(min=dt_init_floor)
        with torch.no_grad():
            self.dt_proj.bias.copy_(dt + torch.log(-torch.expm1(-dt)))  # inverse of softplus
        self.A_log = nn.Parameter(torch.log(torch.arange(1, d_state + 1, dtype=torch.float32)).repeat(d_inner, 1))
        self.D = nn.Parameter(torch.ones(d_inner))

    def forward(self, x: Tensor, z: Tensor | None = None, mask: Tensor | None = None) -> Tensor:
        """x, z (B, L, d_inner); mask (B, L) bool, True = a real frame."""
        dt, B, C = self.x_proj(x).split([self.dt_rank, self.d_state, self.d_state], dim=-1)
        delta = (dt @ self.dt_proj.weight.t()).transpose(1, 2)  # bias goes in the scan, before the softplus
        y = selective_scan(
            x.transpose(1, 2),
            delta,
            -torch.exp(_at_least_float32(self.A_log)),
            B.transpose(1, 2),
            C.transpose(1, 2),
            _at_least_float32(self.D),
            z=None if z is None else z.transpose(1, 2),
            delta_bias=_at_least_float32(self.dt_proj.bias),
            mask=mask,
            reverse=self.reverse,
        )
        return y.transpose(1, 2)


def _at_least_float32(p: Tensor) -> Tensor:
    """SSM parameters in float32 even in a half-precision model (as mamba-ssm keeps them); float64 stays float64."""
    return p.to(torch.promote_types(p.dtype, torch.float32))


def causal_conv1d(conv: nn.Conv1d, x: Tensor, anticausal: bool = False) -> Tensor:
    """Causal depthwise conv over (B, L, C) (mamba's conv1d, with ``conv``'s weights); ``anticausal`` mirrors it in
    time for a reverse scan, so a reverse layer equals the forward layer run on the time-flipped sequence.

    y_t = bias + sum_k w_k x_{t-(K-1)+k}, as K multiply-adds of shifted (B, L, C) slabs: this keeps channels
    innermost, the layout of the Linear layers and of the scan, where F.conv1d wants (B, C, L) and a transpose each
    way.
    """
    width, length = conv.kernel_size[0], x.shape[1]
    weight = conv.weight[:, 0, :]  # (C, K)
    padded = F.pad(x, (0, 0, 0, width - 1) if anticausal else (0, 0, width - 1, 0))
    starts = [width - 1 - k for k in range(width)] if anticausal else list(range(width))
    y = x * weight[:, width - 1] if conv.bias is None else torch.addcmul(conv.bias, x, weight[:, width - 1])
    for k, start in enumerate(starts[:-1]):
        y.addcmul_(padded[:, start : start + length], weight[:, k])  # in place: one (B, L, C) buffer, not K
    return y


def _zero_padding(x: Tensor, mask: Tensor | None) -> Tensor:
    """Padded frames -> 0: before a conv, so they look exactly like its own zero padding; and on the outputs."""
    return x if mask is None else x * mask[..., None].to(x.dtype)


class MambaLayer(nn.Module):
    """The Mamba block mixer (Gu & Dao 2023, Fig. 3): in_proj -> (x, z); x -> causal depthwise conv -> SiLU -> SSM;
    y * silu(z) -> out_proj. (B, L, d_model) -> (B, L, d_model).

    ``reverse=True`` scans from the end with a time-mirrored conv, i.e. it is the forward layer applied to the
    flipped sequence (and flipped back).
    """

    def __init__(
        self,
        d_model: int,
        d_state: int = 16,
        expand: int = 2,
        d_conv: int = 4,
        dt_rank: int | None = None,
        reverse: bool = False,
        bias: bool = False,
    ) -> None:
        super().__init__()
        d_inner = expand * d_model
        self.reverse = reverse
        self.in_proj = nn.Linear(d_model, 2 * d_inner, bias=bias)
        self.conv1d = nn.Conv1d(d_inner, d_inner, d_conv, groups=d_inner)  # padded in causal_conv1d
        self.ssm = SelectiveSSM(d_inner, d_state, dt_rank if dt_rank is not None else math.ceil(d_model / 16), reverse)
        self.out_proj = nn.Linear(d_inner, d_model, bias=bias)

    def forward(self, hidden: Tensor, mask: Tensor | None = None) -> Tensor:
        """hidden (B, L, d_model); mask (B, L) bool, True = a real frame (outputs at padded frames are 0)."""
        x, z = self.in_proj(hidden).chunk(2, dim=-1)
        x = F.silu(causal_conv1d(self.conv1d, _zero_padding(x, mask), anticausal=self.reverse))
        return _zero_padding(self.out_proj(self.ssm(x, z, mask)), mask)


class BiMamba(nn.Module):
    """Bidirectional Mamba mixer for UMSD Eq. 7: y = Phi+(mu(x)) + Phi-(mu(x)), gated and projected back.

    One input projection, one causal conv mu and one gate/out projection are shared; only the SSMs (x_proj,
    dt_proj, A, D) are per direction. Why shared: Eq. 7 feeds the same LN(D^{i-1}) and mu(.) to both Phi+ and
    Phi- and sums them, and in_proj + out_proj are most of a Mamba layer's matmul FLOPs, so two full MambaLayers
    would cost about twice as much for no term of Eq. 7. Summing (not concatenating) also follows Eq. 7.
    (B, L, d_model) -> (B, L, d_model).
    """

    def __init__(
        self, d_model: int, d_state: int = 16, expand: int = 2, d_conv: int = 4, dt_rank: int | None = None
    ) -> None:
        super().__init__()
        d_inner = expand * d_model
        dt_rank = dt_rank if dt_rank is not None else math.ceil(d_model / 16)
        self.in_proj = nn.Linear(d_model, 2 * d_inner, bias=False)
        self.conv1d = nn.Conv1d(d_inner, d_inner, d_conv, groups=d_inner)  # padded in causal_conv1d
        self.forward_ssm = SelectiveSSM(d_inner, d_state, dt_rank, reverse=False)
        self.backward_ssm = SelectiveSSM(d_inner, d_state, dt_rank, reverse=True)
        self.out_proj = nn.Linear(d_inner, d_model, bias=False)

    def forward(self, hidden: Tensor, mask: Tensor | None = None) -> Tensor:
        """hidden (B, L, d_model); mask (B, L) bool, True = a real frame (outputs at padded frames are 0)."""
        x, z = self.in_proj(hidden).chunk(2, dim=-1)
        x = F.silu(causal_conv1d(self.conv1d, _zero_padding(x, mask), anticausal=False))
        y = self.forward_ssm(x, mask=mask) + self.backward_ssm(x, mask=mask)
        return _zero_padding(self.out_proj(y * F.silu(z)), mask)
