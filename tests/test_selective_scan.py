"""The chunked selective scan equals the sequential recurrence (values and gradients), masks do not leak, long and
strongly decaying sequences stay finite, and the Mamba / bidirectional layers train."""

from __future__ import annotations

import threading

import pytest
import torch

from motionaug.models.selective_scan import (
    BiMamba,
    MambaLayer,
    _cuda_kernel,
    _ScanWorkers,
    causal_conv1d,
    selective_scan,
    selective_scan_reference,
)

torch.set_num_threads(1)
F64 = torch.float64
NAMES = ("u", "delta", "A", "B", "C", "D", "z", "delta_bias")


@pytest.fixture(autouse=True)
def _seed() -> None:
    torch.manual_seed(0)  # the cotangents and layer weights below; inputs come from their own seeded generator


def make_inputs(batch: int, channels: int, state: int, length: int, seed: int = 0) -> dict:
    g = torch.Generator().manual_seed(seed)

    def rand(*shape):
        return torch.randn(*shape, generator=g, dtype=F64)

    return {
        "u": rand(batch, channels, length),
        "delta": rand(batch, channels, length),
        "A": -(torch.rand(channels, state, generator=g, dtype=F64) * 3 + 0.05),
        "B": rand(batch, state, length),
        "C": rand(batch, state, length),
        "D": rand(channels),
        "z": rand(batch, channels, length),
        "delta_bias": rand(channels) * 0.5,
    }


def leaves(inputs: dict, dtype=F64) -> dict:
    return {k: v.detach().to(dtype).requires_grad_() for k, v in inputs.items()}


def value_and_grads(fn, inputs: dict, weight: torch.Tensor, **kwargs) -> tuple[torch.Tensor, dict]:
    """y and d(sum(y * weight))/d(every input): a random cotangent, so every output position matters."""
    y = fn(**inputs, **kwargs)
    grads = torch.autograd.grad((y * weight.to(y.dtype)).sum(), list(inputs.values()))
    return y.detach(), dict(zip(inputs, grads, strict=True))


def assert_close_all(got: tuple, want: tuple, rtol: float, atol: float) -> None:
    (y, grads), (y_ref, grads_ref) = got, want
    torch.testing.assert_close(y.to(F64), y_ref, rtol=rtol, atol=atol)
    for name in grads_ref:
        torch.testing.assert_close(grads[name].to(F64), grads_ref[name], rtol=rtol, atol=atol, msg=name)


def ragged_mask(lengths: list[int], total: int) -> torch.Tensor:
    return torch.arange(total)[None, :] < torch.tensor(lengths)[:, None]


@pytest.mark.parametrize("reverse", [False, True])
@pytest.mark.parametrize("length", [1, 7, 63, 197])
def test_matches_reference_float64(length: int, reverse: bool) -> None:
    inputs = make_inputs(2, 5, 3, length, seed=length)
    weight = torch.randn(2, 5, length, dtype=F64)
    mask = ragged_mask([length, max(1, length - 4)], length)
    for kwargs in ({}, {"mask": mask}):
        want = value_and_grads(selective_scan_reference, leaves(inputs), weight, reverse=reverse, **kwargs)
        got = value_and_grads(selective_scan, leaves(inputs), weight, reverse=reverse, **kwargs)
        assert_close_all(got, want, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("reverse", [False, True])
@pytest.mark.parametrize("chunk", [1, 4, 16])
def test_chunk_boundaries(chunk: int, reverse: bool) -> None:
    for length in sorted({1, chunk - 1, chunk, chunk + 1, 2 * chunk, 2 * chunk + 1, 3 * chunk - 1} - {0}):
        inputs = make_inputs(2, 4, 3, length, seed=100 + length)
        weight = torch.randn(2, 4, length, dtype=F64)
        want = value_and_grads(selective_scan_reference, leaves(inputs), weight, reverse=reverse)
        got = value_and_grads(selective_scan, leaves(inputs), weight, reverse=reverse, chunk_size=chunk)
        assert_close_all(got, want, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("reverse", [False, True])
def test_worker_threads_match_reference(reverse: bool) -> None:
    """Channel groups on worker threads (7 channels over 3 workers: uneven groups); d_B and d_C sum across groups."""
    inputs = make_inputs(2, 7, 3, 45, seed=23)
    weight = torch.randn(2, 7, 45, dtype=F64)
    mask = ragged_mask([45, 30], 45)
    want = value_and_grads(selective_scan_reference, leaves(inputs), weight, reverse=reverse, mask=mask)
    got = value_and_grads(selective_scan, leaves(inputs), weight, reverse=reverse, mask=mask, workers=3, chunk_size=8)
    assert_close_all(got, want, rtol=1e-9, atol=1e-9)


def test_worker_threads_leave_the_thread_setting_alone(monkeypatch: pytest.MonkeyPatch) -> None:
    """Workers set themselves to one intra-op thread, which also writes PyTorch's process-wide default: it must be
    restored for the caller and for threads started later."""
    monkeypatch.setattr(_ScanWorkers, "_pool", None)  # start a fresh pool in this test
    torch.set_num_threads(2)
    try:
        y = selective_scan(**make_inputs(2, 4, 3, 10, seed=29), workers=2)
        seen: list[int] = []
        thread = threading.Thread(target=lambda: seen.append(torch.get_num_threads()))
        thread.start()
        thread.join()
        assert torch.get_num_threads() == 2 and seen == [2]
        assert torch.isfinite(y).all()
    finally:
        torch.set_num_threads(1)


def test_optional_arguments_match_reference() -> None:
    """No D, no gate, no bias, no softplus (delta used as given, so it must be >= 0 for a decaying state)."""
    inputs = make_inputs(2, 4, 3, 29, seed=7)
    inputs = {k: v for k, v in inputs.items() if k in ("u", "delta", "A", "B", "C")}
    inputs["delta"] = inputs["delta"].abs()
    weight = torch.randn(2, 4, 29, dtype=F64)
    for reverse in (False, True):
        kwargs = {"delta_softplus": False, "reverse": reverse}
        want = value_and_grads(selective_scan_reference, leaves(inputs), weight, **kwargs)
        got = value_and_grads(selective_scan, leaves(inputs), weight, chunk_size=8, **kwargs)
        assert_close_all(got, want, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("reverse", [False, True])
def test_float32_matches_float64_reference(reverse: bool) -> None:
    """float32 fast path vs the float64 truth: within 1e-5 of the largest magnitude (we see ~3e-7)."""
    inputs = make_inputs(3, 8, 16, 197, seed=3)
    weight = torch.randn(3, 8, 197, dtype=F64)
    y_ref, grads_ref = value_and_grads(selective_scan_reference, leaves(inputs), weight, reverse=reverse)
    y, grads = value_and_grads(selective_scan, leaves(inputs, torch.float32), weight, reverse=reverse, chunk_size=16)
    assert y.dtype == torch.float32
    for name, got, want in [("y", y, y_ref)] + [(k, grads[k], grads_ref[k]) for k in NAMES]:
        torch.testing.assert_close(got.to(F64), want, rtol=0, atol=1e-5 * float(want.abs().max()), msg=name)


def test_reference_is_the_ssm_convolution() -> None:
    """The reference itself against the unrolled SSM (Gu & Dao 2023, Eq. 2a/2b with ZOH A, Euler B):
    y_t = sum_{s<=t} <C_t, exp(A sum_{r=s+1..t} delta_r) delta_s B_s u_s> + D u_t, gated; reverse mirrors s <= t."""
    inputs = make_inputs(2, 3, 4, 11, seed=5)
    u, A, B, C, D, z = (inputs[k] for k in ("u", "A", "B", "C", "D", "z"))
    delta = torch.nn.functional.softplus(inputs["delta"] + inputs["delta_bias"][:, None])
    for reverse in (False, True):
        y = torch.zeros_like(u)
        for t in range(u.shape[-1]):
            sources = range(t, u.shape[-1]) if reverse else range(t + 1)
            for s in sources:
                between = delta[:, :, s + 1 : t + 1] if not reverse else delta[:, :, t:s]
                decay = torch.exp(between.sum(-1)[..., None] * A)  # (B, D, N)
                contrib = decay * (delta[:, :, s, None] * B[:, None, :, s] * u[:, :, s, None])
                y[:, :, t] += (contrib * C[:, None, :, t]).sum(-1)
        y = (y + D[:, None] * u) * torch.nn.functional.silu(z)
        torch.testing.assert_close(selective_scan_reference(**inputs, reverse=reverse), y, rtol=1e-12, atol=1e-12)


def test_gradcheck_fast_path() -> None:
    """The hand-written backward against finite differences, independent of the reference."""
    inputs = leaves(make_inputs(1, 2, 2, 6, seed=9))
    for reverse in (False, True):
        assert torch.autograd.gradcheck(
            lambda *args, r=reverse: selective_scan(*args, reverse=r, chunk_size=4), tuple(inputs.values())
        )


@pytest.mark.parametrize("reverse", [False, True])
def test_padding_does_not_leak(reverse: bool) -> None:
    """Each sequence of a right-padded batch (padding filled with huge values) equals the scan of that sequence
    alone, in values and input gradients; padded outputs are 0 and padded inputs get no gradient."""
    lengths, total = [23, 17, 1], 23
    mask = ragged_mask(lengths, total)
    inputs = make_inputs(3, 4, 5, total, seed=11)
    per_sequence = ("u", "delta", "z", "B", "C")
    for key in per_sequence:
        inputs[key] = inputs[key].masked_fill(~mask[:, None, :], 1e4)
    batch = leaves(inputs)
    weight = torch.randn(3, 4, total, dtype=F64)
    y = selective_scan(**batch, mask=mask, reverse=reverse, chunk_size=4)
    grads = dict(zip(batch, torch.autograd.grad((y * weight).sum(), list(batch.values())), strict=True))
    assert torch.all(y[~mask[:, None, :].expand_as(y)] == 0)
    for i, n in enumerate(lengths):
        alone = {k: (v[i : i + 1, ..., :n] if v.dim() == 3 else v) for k, v in leaves(inputs).items()}
        y_alone = selective_scan(**alone, reverse=reverse, chunk_size=4)
        grads_alone = torch.autograd.grad((y_alone * weight[i : i + 1, :, :n]).sum(), [alone[k] for k in per_sequence])
        torch.testing.assert_close(y[i : i + 1, :, :n], y_alone, rtol=1e-10, atol=1e-10)
        for key, g_alone in zip(per_sequence, grads_alone, strict=True):
            torch.testing.assert_close(grads[key][i : i + 1, :, :n], g_alone, rtol=1e-10, atol=1e-10)
        for key in per_sequence:
            assert torch.all(grads[key][i, :, n:] == 0), key


@pytest.mark.parametrize("reverse", [False, True])
def test_masked_steps_are_skipped_anywhere(reverse: bool) -> None:
    """A mask with holes and leading padding: masked steps leave the state untouched (delta = 0, not just u = 0),
    so the valid outputs equal the scan of the compacted sequence, and match the reference's skip semantics."""
    length = 30
    mask = torch.rand(2, length, generator=torch.Generator().manual_seed(1)) > 0.4
    mask[1, :5] = False
    inputs = make_inputs(2, 4, 3, length, seed=21)
    weight = torch.randn(2, 4, length, dtype=F64)
    got = value_and_grads(selective_scan, leaves(inputs), weight, mask=mask, reverse=reverse, chunk_size=4)
    want = value_and_grads(selective_scan_reference, leaves(inputs), weight, mask=mask, reverse=reverse)
    assert_close_all(got, want, rtol=1e-9, atol=1e-9)
    for i in range(2):
        keep = mask[i].nonzero().squeeze(1)
        compact = {k: (v[i : i + 1].index_select(-1, keep) if v.dim() == 3 else v) for k, v in inputs.items()}
        y_compact = selective_scan(**compact, reverse=reverse)
        torch.testing.assert_close(got[0][i : i + 1].index_select(-1, keep), y_compact, rtol=1e-10, atol=1e-10)


def test_long_sequence_with_strong_decay_stays_finite() -> None:
    """Per-step log-decays delta*A down to about -4000 and a cumulative log-decay beyond -1e5, so exp(-S) of a
    log-space scan would overflow even in float64; here values and gradients stay finite and exact."""
    length = 3000
    inputs = make_inputs(2, 4, 6, length, seed=13)
    inputs["A"] = -torch.logspace(0, 3, 24, dtype=F64).view(4, 6)
    inputs["delta"] = inputs["delta"].abs() + 1.0  # softplus(delta + bias) ~ 1-4
    delta = torch.nn.functional.softplus(inputs["delta"] + inputs["delta_bias"][:, None])
    assert float((delta.sum(-1)[..., None] * inputs["A"]).min()) < -1e5  # the regime a log-space form cannot hold
    weight = torch.randn(2, 4, length, dtype=F64)
    for dtype in (torch.float32, F64):
        y, grads = value_and_grads(selective_scan, leaves(inputs, dtype), weight, reverse=dtype == F64)
        assert torch.isfinite(y).all() and all(torch.isfinite(g).all() for g in grads.values())
    short = {k: (v[..., :300] if v.dim() == 3 else v) for k, v in inputs.items()}
    for reverse in (False, True):
        want = value_and_grads(selective_scan_reference, leaves(short), weight[..., :300], reverse=reverse)
        got = value_and_grads(selective_scan, leaves(short), weight[..., :300], reverse=reverse)
        assert_close_all(got, want, rtol=1e-9, atol=1e-9)


def test_bfloat16_inputs_compute_in_float32() -> None:
    inputs = make_inputs(2, 4, 3, 40, seed=17)
    y32 = selective_scan(**{k: v.float() for k, v in inputs.items()})
    y16 = selective_scan(**{k: v.bfloat16() for k, v in inputs.items()})
    assert y16.dtype == torch.bfloat16
    torch.testing.assert_close(y16.float(), y32, rtol=0.05, atol=0.05 * float(y32.abs().max()))


@pytest.mark.skipif(not torch.cuda.is_available() or _cuda_kernel() is None, reason="needs CUDA and mamba_ssm")
def test_cuda_kernel_dispatch_matches_chunked_scan() -> None:
    inputs = make_inputs(2, 8, 16, 50, seed=19)
    mask = ragged_mask([50, 31], 50)
    for reverse in (False, True):
        want = selective_scan(**{k: v.float() for k, v in inputs.items()}, mask=mask, reverse=reverse)
        got = selective_scan(**{k: v.float().cuda() for k, v in inputs.items()}, mask=mask.cuda(), reverse=reverse)
        torch.testing.assert_close(got.cpu(), want, rtol=1e-4, atol=1e-4)


def test_layers_keep_shape() -> None:
    x = torch.randn(3, 13, 16)
    for layer in (MambaLayer(16), MambaLayer(16, reverse=True), BiMamba(16)):
        y = layer(x)
        assert y.shape == x.shape and torch.isfinite(y).all()
        assert layer.in_proj.out_features == 2 * 2 * 16  # expand = 2


def test_causal_conv_is_mambas_conv1d() -> None:
    """causal_conv1d equals nn.Conv1d over the left-zero-padded sequence (mamba's conv1d, truncated to L); the
    anticausal one is the causal one on flipped time."""
    conv = torch.nn.Conv1d(6, 6, 4, groups=6).double()
    x = torch.randn(2, 9, 6, dtype=F64)
    want = torch.nn.functional.conv1d(x.transpose(1, 2), conv.weight, conv.bias, padding=3, groups=6)[..., :9]
    torch.testing.assert_close(causal_conv1d(conv, x), want.transpose(1, 2))
    torch.testing.assert_close(causal_conv1d(conv, x, anticausal=True), causal_conv1d(conv, x.flip(1)).flip(1))


def test_reverse_layer_is_the_forward_layer_on_flipped_time() -> None:
    forward, backward = MambaLayer(8), MambaLayer(8, reverse=True)
    backward.load_state_dict(forward.state_dict())
    x = torch.randn(2, 19, 8)
    torch.testing.assert_close(backward(x), forward(x.flip(1)).flip(1), rtol=1e-5, atol=1e-5)
    assert not torch.allclose(backward(x), forward(x), atol=1e-3)


@pytest.mark.parametrize(
    "make", [lambda: MambaLayer(8), lambda: MambaLayer(8, reverse=True, bias=True), lambda: BiMamba(8)]
)
def test_layer_padding_does_not_leak(make) -> None:
    """conv + both scans: the valid frames of a padded batch equal each sequence run alone; padded frames are 0."""
    layer = make().double()
    lengths, total = [21, 12], 21
    mask = ragged_mask(lengths, total)
    x = torch.randn(2, total, 8, dtype=F64).masked_fill(~mask[..., None], 50.0)
    y = layer(x, mask)
    assert torch.all(y[~mask] == 0)
    for i, n in enumerate(lengths):
        torch.testing.assert_close(y[i : i + 1, :n], layer(x[i : i + 1, :n]), rtol=1e-10, atol=1e-10)


def test_layers_train_and_bimamba_uses_both_directions() -> None:
    """A tiny regression whose target at t needs the past and the future (a centred moving average): Adam steps
    must cut every layer's loss, every parameter must get a gradient, and BiMamba must fit it clearly better than
    either one-directional layer."""
    x = torch.randn(16, 24, 4)
    target = torch.nn.functional.conv1d(x[..., :1].transpose(1, 2), torch.ones(1, 1, 7) / 7, padding=3).transpose(1, 2)
    final = {}
    for name, make in [("bi", BiMamba), ("forward", MambaLayer), ("backward", lambda d: MambaLayer(d, reverse=True))]:
        torch.manual_seed(0)
        model = torch.nn.Sequential(torch.nn.Linear(4, 16), make(16), torch.nn.Linear(16, 1))
        optimiser = torch.optim.Adam(model.parameters(), lr=1e-2)
        losses = []
        for _ in range(40):
            loss = torch.nn.functional.mse_loss(model(x), target)
            optimiser.zero_grad()
            loss.backward()
            if not losses:
                for param_name, p in model.named_parameters():
                    assert p.grad is not None and p.grad.abs().sum() > 0, (name, param_name)
            optimiser.step()
            losses.append(loss.item())
        assert losses[-1] < 0.3 * losses[0], (name, losses)
        final[name] = losses[-1]
    assert final["bi"] < 0.6 * min(final["forward"], final["backward"]), final
