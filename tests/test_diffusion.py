"""Diffusion math: schedule, q/posterior formulas, DDPM/DDIM loops and their hooks (no network needed)."""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest
import torch
from torch import Tensor

from motionaug.augment.diffusion import (
    InpaintSpec,
    NoiseSchedule,
    SamplerStep,
    SpectralPrior,
    contrast_guided,
    cosine_betas,
    dct_matrix,
    ddim_path,
    ddim_sample,
    ddim_step,
    ddpm_sample,
    ddpm_step,
    estimate_spectral_prior,
    guided_x0,
    masked_mse,
    off_own_motion,
    q_posterior_mean_variance,
    q_sample,
    skip_x0,
    space_timesteps,
    start_step_for,
)
from motionaug.schemas.errors import MotionDataError

B, T, D = 2, 6, 5


class SmoothDenoiser:
    """A fixed nonlinear x0 predictor (random but seeded), with a condition that guidance can remove."""

    def __init__(self, dtype: torch.dtype = torch.float64) -> None:
        g = torch.Generator().manual_seed(7)
        self.weight = torch.randn(D, D, generator=g, dtype=dtype) / math.sqrt(D)
        self.cond_bias = torch.randn(D, generator=g, dtype=dtype)
        self.calls: list[tuple[Tensor, Tensor, bool]] = []

    def __call__(self, x_t: Tensor, t: Tensor, *, uncond: bool = False) -> Tensor:
        self.calls.append((x_t.clone(), t.clone(), uncond))
        scale = (1.0 - t.to(x_t.dtype) / 1000.0).view(-1, 1, 1)
        out = torch.tanh(x_t @ self.weight) * scale
        return out if uncond else out + self.cond_bias


class Oracle:
    """Always predicts the same clean motion (the best possible denoiser for a one-point data set)."""

    def __init__(self, x0: Tensor) -> None:
        self.x0 = x0

    def __call__(self, x_t: Tensor, t: Tensor, *, uncond: bool = False) -> Tensor:
        return self.x0.clone()


def recorder() -> tuple[list[SamplerStep], Callable[[SamplerStep], None]]:
    steps: list[SamplerStep] = []
    return steps, steps.append


def gen(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


# ---------------------------------------------------------------- schedule


def test_cosine_schedule_values() -> None:
    sched = NoiseSchedule.cosine()
    assert len(sched) == 1000
    assert bool((sched.betas > 0).all()) and float(sched.betas.max()) <= 0.999
    assert float(sched.betas[-1]) == pytest.approx(0.999)  # the clip is active at the end
    assert bool((sched.alphas_cumprod[1:] < sched.alphas_cumprod[:-1]).all())
    f = lambda u: math.cos((u + 0.008) / 1.008 * math.pi / 2) ** 2  # noqa: E731
    for t in (0, 10, 250, 500, 900):  # before the clip, alpha_bar_t = f((t+1)/T) / f(0)
        assert float(sched.alphas_cumprod[t]) == pytest.approx(f((t + 1) / 1000) / f(0), rel=1e-9)
    assert float(sched.posterior_variance[0]) == 0.0
    assert torch.allclose(cosine_betas(1000), sched.betas)


def test_respace_ddim20_keeps_alpha_bar() -> None:
    sched = NoiseSchedule.cosine()
    spaced = sched.respace(20)
    assert spaced.timesteps.tolist() == list(range(0, 1000, 50))
    assert torch.allclose(spaced.alphas_cumprod, sched.alphas_cumprod[spaced.timesteps], rtol=1e-12)
    assert space_timesteps(1000, "ddim20") == list(range(0, 1000, 50))
    assert space_timesteps(1000, 30) == list(range(0, 1000, 34))  # an integer stride exists: "ddim30"
    assert len(space_timesteps(1000, 999)) == 999  # no integer stride: evenly rounded, like MDM's "999"
    assert space_timesteps(100, "10,5")[:10] == [0, 5, 11, 16, 22, 27, 33, 38, 44, 49]
    with pytest.raises(MotionDataError):
        space_timesteps(1000, "ddim999")
    with pytest.raises(MotionDataError):
        spaced.respace(10)


def test_start_step_for_maps_k300_to_6_of_20() -> None:
    assert start_step_for(300, 20) == 6
    assert start_step_for(1000, 20) == 20
    assert start_step_for(0, 20) == 1
    with pytest.raises(MotionDataError):
        start_step_for(1200, 20)


# ---------------------------------------------------------------- q and posterior


def test_q_sample_statistics() -> None:
    sched = NoiseSchedule.cosine()
    n = 40000
    x0 = torch.linspace(-2, 2, 3, dtype=torch.float64).view(1, 1, 3).expand(n, 1, 3)
    for t_val in (100, 600):
        t = torch.full((n,), t_val)
        x_t = q_sample(sched, x0, t, torch.randn(x0.shape, generator=gen(t_val), dtype=torch.float64))
        ab = float(sched.alphas_cumprod[t_val])
        se = math.sqrt((1 - ab) / n)
        assert torch.allclose(x_t.mean(0), math.sqrt(ab) * x0[0], atol=5 * se)
        assert torch.allclose(x_t.var(0), torch.full((1, 3), 1 - ab, dtype=torch.float64), rtol=0.05)


def test_posterior_matches_gaussian_conditioning() -> None:
    """q(x_{t-1} | x_t, x_0) equals conditioning the joint Gaussian of (x_{t-1}, x_t) given x_0."""
    sched = NoiseSchedule.cosine()
    x0 = torch.randn(B, T, D, generator=gen(1), dtype=torch.float64)
    x_t = torch.randn(B, T, D, generator=gen(2), dtype=torch.float64)
    for t_val in (1, 37, 500, 998):
        ab, ab_prev, alpha = (
            float(v) for v in (sched.alphas_cumprod[t_val], sched.alphas_cumprod[t_val - 1], sched.alphas[t_val])
        )
        cov = math.sqrt(alpha) * (1 - ab_prev)
        want_mean = math.sqrt(ab_prev) * x0 + cov / (1 - ab) * (x_t - math.sqrt(ab) * x0)
        want_var = (1 - ab_prev) - cov**2 / (1 - ab)
        mean, var, _ = q_posterior_mean_variance(sched, x0, x_t, torch.full((B,), t_val))
        assert torch.allclose(mean, want_mean, atol=1e-10)
        assert float(var.flatten()[0]) == pytest.approx(want_var, rel=1e-9)


# ---------------------------------------------------------------- DDPM vs DDIM


def test_ddim_eta1_unspaced_is_ddpm_step_for_step() -> None:
    """Precise statement: DDIM with S = T and eta = 1 has sigma_t^2 = beta_tilde_t, so with the same noise
    it IS ancestral DDPM (same x_t and same x0 predictions at all 1000 steps), and its noise-free part is the
    DDPM posterior mean. (eta = 0 is a different, deterministic path; see test_ddim_eta0_stays_on_q_path.)"""
    model = SmoothDenoiser()
    a, on_a = recorder()
    b, on_b = recorder()
    out_ddpm = ddpm_sample(model, (B, T, D), generator=gen(3), progress=on_a, dtype=torch.float64)
    out_ddim = ddim_sample(model, (B, T, D), steps=None, eta=1.0, generator=gen(3), progress=on_b, dtype=torch.float64)
    assert len(a) == len(b) == 1000
    for sa, sb in zip(a, b, strict=True):
        assert sa.timestep == sb.timestep
        assert torch.allclose(sa.pred_x0, sb.pred_x0, atol=1e-9)
        assert torch.allclose(sa.x_t, sb.x_t, atol=1e-9)
    assert torch.allclose(out_ddpm, out_ddim, atol=1e-9)
    sched = NoiseSchedule.cosine()
    x, x0_hat = a[500].x_t, a[500].pred_x0
    for index in (1, 300, 999):  # the noise-free DDPM update (posterior mean) == DDIM eta=1 without noise
        assert torch.allclose(
            ddpm_step(sched, x, x0_hat, index, None), ddim_step(sched, x, x0_hat, index, 1.0, None), atol=1e-12
        )


def test_ddim_eta0_stays_on_q_path() -> None:
    """With a perfect denoiser, DDIM (eta=0) keeps the implied noise fixed: x_t = sqrt(ab_t) x0 + sqrt(1-ab_t) eps."""
    x0 = torch.randn(B, T, D, generator=gen(4), dtype=torch.float64)
    noise = torch.randn(B, T, D, generator=gen(5), dtype=torch.float64)
    sched = NoiseSchedule.cosine().respace(20)
    steps, on_step = recorder()
    out = ddim_sample(Oracle(x0), (B, T, D), noise=noise, progress=on_step, dtype=torch.float64)
    eps = (noise - sched.sqrt_alphas_cumprod[-1] * x0) / sched.sqrt_one_minus_alphas_cumprod[-1]
    for step in steps[:-1]:
        want = q_sample(sched, x0, torch.full((B,), step.index - 1), eps)
        assert torch.allclose(step.x_t, want, atol=1e-9)
    assert torch.equal(out, x0)


def test_sampling_is_deterministic_per_seed() -> None:
    model = SmoothDenoiser(torch.float32)
    one = ddim_sample(model, (B, T, D), steps=10, eta=0.5, generator=gen(9))
    two = ddim_sample(model, (B, T, D), steps=10, eta=0.5, generator=gen(9))
    three = ddim_sample(model, (B, T, D), steps=10, eta=0.5, generator=gen(10))
    assert torch.equal(one, two) and not torch.allclose(one, three)
    assert one.dtype == torch.float32 and one.shape == (B, T, D)


# ---------------------------------------------------------------- start step


def test_start_step_noises_x_start_and_runs_last_steps() -> None:
    model = SmoothDenoiser()
    x_start = torch.randn(B, T, D, generator=gen(11), dtype=torch.float64)
    noise = torch.randn(B, T, D, generator=gen(12), dtype=torch.float64)
    n = start_step_for(300, 20)
    ddim_sample(model, (B, T, D), steps=20, start_step=n, x_start=x_start, noise=noise, dtype=torch.float64)
    assert [int(c[1][0]) for c in model.calls] == [250, 200, 150, 100, 50, 0]
    spaced = NoiseSchedule.cosine().respace(20)
    want_first = q_sample(spaced, x_start, torch.full((B,), n - 1), noise)
    assert torch.allclose(model.calls[0][0], want_first, atol=1e-12)
    full = NoiseSchedule.cosine()  # respaced index 5 has the noise level of training timestep 250
    assert torch.allclose(want_first, q_sample(full, x_start, torch.full((B,), 250), noise), atol=1e-12)
    model.calls.clear()
    ddpm_sample(model, (B, T, D), start_step=3, x_start=x_start, generator=gen(1), dtype=torch.float64)
    assert [int(c[1][0]) for c in model.calls] == [2, 1, 0]
    with pytest.raises(MotionDataError):
        ddim_sample(model, (B, T, D), start_step=6)
    with pytest.raises(MotionDataError):
        ddim_sample(model, (B, T, D), start_step=21, x_start=x_start)


def test_start_step_with_oracle_returns_x_start() -> None:
    x_start = torch.randn(B, T, D, generator=gen(13), dtype=torch.float64)
    out = ddim_sample(Oracle(x_start), (B, T, D), start_step=6, x_start=x_start, generator=gen(2), dtype=torch.float64)
    assert torch.equal(out, x_start)


# ---------------------------------------------------------------- inpainting


@pytest.mark.parametrize("sampler", ["ddim", "ddim_eta", "ddpm_spaced", "ddim_start"])
def test_inpainted_channels_equal_reference(sampler: str) -> None:
    model = SmoothDenoiser(torch.float32)
    reference = torch.randn(B, T, D, generator=gen(14))
    spec = InpaintSpec(reference, channels=[0, 3])
    steps, on_step = recorder()
    kwargs = dict(inpaint=spec, progress=on_step, generator=gen(15))
    if sampler == "ddim":
        out = ddim_sample(model, (B, T, D), **kwargs)
    elif sampler == "ddim_eta":
        out = ddim_sample(model, (B, T, D), eta=1.0, **kwargs)
    elif sampler == "ddpm_spaced":
        out = ddpm_sample(model, (B, T, D), steps=50, **kwargs)
    else:
        x_start = torch.randn(B, T, D, generator=gen(16))
        out = ddim_sample(model, (B, T, D), start_step=6, x_start=x_start, **kwargs)
    channels = [0, 3]
    for step in steps:
        assert torch.equal(step.pred_x0[..., channels], reference[..., channels])
    assert torch.equal(out[..., channels], reference[..., channels])
    assert not torch.allclose(out[..., [1, 2, 4]], reference[..., [1, 2, 4]])
    sched = NoiseSchedule.cosine().respace(50 if sampler == "ddpm_spaced" else 20)
    mid = steps[len(steps) // 2]  # no noise on those channels: they ride the zero-noise q-path of the reference
    ab_prev = float(sched.alphas_cumprod[mid.index - 1])
    assert torch.allclose(mid.x_t[..., channels], math.sqrt(ab_prev) * reference[..., channels], atol=1e-5)


def test_inpaint_frames_and_bool_channels() -> None:
    reference = torch.randn(B, T, D, generator=gen(17))
    frames = torch.zeros(T, dtype=torch.bool)
    frames[:2] = True
    channels = torch.tensor([True, False, False, False, True])
    out = ddim_sample(
        SmoothDenoiser(torch.float32), (B, T, D), inpaint=InpaintSpec(reference, channels, frames), generator=gen(1)
    )
    assert torch.equal(out[:, :2][..., channels], reference[:, :2][..., channels])
    assert not torch.allclose(out[:, 2:][..., channels], reference[:, 2:][..., channels])
    with pytest.raises(MotionDataError):
        InpaintSpec(reference, [D]).mask()
    with pytest.raises(MotionDataError):
        ddim_sample(SmoothDenoiser(), (B, T + 1, D), inpaint=InpaintSpec(reference, [0]))


# ---------------------------------------------------------------- guidance


def test_cfg_scale_one_is_conditional_and_zero_unconditional() -> None:
    model = SmoothDenoiser()
    x = torch.randn(B, T, D, generator=gen(18), dtype=torch.float64)
    t = torch.full((B,), 400)
    assert torch.allclose(guided_x0(model, x, t, 1.0), model(x, t), atol=1e-12)
    assert torch.allclose(guided_x0(model, x, t, 0.0), model(x, t, uncond=True), atol=1e-12)
    assert torch.allclose(guided_x0(model, x, t, 2.5), model(x, t, uncond=True) + 2.5 * model.cond_bias, atol=1e-12)
    plain = ddim_sample(model, (B, T, D), generator=gen(19), dtype=torch.float64)
    guided = ddim_sample(model, (B, T, D), guidance_scale=1.0, generator=gen(19), dtype=torch.float64)
    strong = ddim_sample(model, (B, T, D), guidance_scale=3.0, generator=gen(19), dtype=torch.float64)
    assert torch.allclose(plain, guided, atol=1e-9)
    assert not torch.allclose(plain, strong, atol=1e-3)


def test_contrast_guidance_extrapolates_from_the_reference() -> None:
    tuned, base = SmoothDenoiser(), SmoothDenoiser()
    base.cond_bias = -base.cond_bias
    x = torch.randn(B, T, D, generator=gen(22), dtype=torch.float64)
    t = torch.full((B,), 300)
    assert torch.allclose(contrast_guided(tuned, base, 1.0)(x, t), tuned(x, t), atol=1e-12)
    assert torch.allclose(contrast_guided(tuned, base, 0.0)(x, t), base(x, t), atol=1e-12)
    expected = base(x, t) + 2.0 * (tuned(x, t) - base(x, t))
    assert torch.allclose(contrast_guided(tuned, base, 2.0)(x, t), expected, atol=1e-12)
    unconditional = contrast_guided(tuned, base, 2.0)(x, t, uncond=True)  # both sides lose their condition
    assert torch.allclose(unconditional, tuned(x, t, uncond=True), atol=1e-12)


def test_guidance_off_the_own_motion_keeps_posture_and_new_motion_but_not_gesture_scaling() -> None:
    """A direction that shrinks the reference's gestures loses that part; a posture shift and a new swing stay."""
    frames_n = 64
    time = torch.arange(frames_n, dtype=torch.float64)[None, :, None].expand(B, frames_n, D) / frames_n
    gesture = torch.sin(2 * math.pi * 2 * time)  # the reference's own motion
    reference = 3.0 + gesture  # an offset is posture, not motion
    swing = torch.cos(2 * math.pi * 5 * time)  # a motion the reference lacks (orthogonal to its gesture)
    direction = -0.5 * gesture + 0.7 + 0.2 * swing
    kept = off_own_motion(direction, reference)
    assert torch.allclose(kept, 0.7 + 0.2 * swing, atol=1e-9)  # the shrinking is gone, posture + swing kept
    assert torch.allclose(off_own_motion(kept, reference), kept, atol=1e-9)  # a projection: idempotent
    # padded frames neither count nor change; a still reference (no own motion) leaves the direction whole
    half = frames_n // 2
    frames = torch.ones(B, frames_n, dtype=torch.bool)
    frames[:, half:] = False
    padded = reference.clone()
    padded[:, half:] = 1e6
    masked = off_own_motion(direction, padded, frames)
    assert torch.equal(masked[:, half:], direction[:, half:])
    own = padded[:, :half] - padded[:, :half].mean(dim=1, keepdim=True)
    assert torch.allclose((masked[:, :half] * own).sum(dim=1), torch.zeros(B, D, dtype=torch.float64), atol=1e-9)
    still = torch.full_like(reference, 2.0)
    assert torch.equal(off_own_motion(direction, still), direction)


# ---------------------------------------------------------------- loss and differentiable path


def test_masked_mse_ignores_padding_even_nan() -> None:
    pred = torch.randn(B, T, D, generator=gen(20))
    target = torch.randn(B, T, D, generator=gen(21))
    mask = torch.ones(B, T, dtype=torch.bool)
    mask[1, 4:] = False
    poisoned = target.clone()
    poisoned[1, 4:] = float("nan")
    loss = masked_mse(pred, poisoned, mask)
    assert torch.isfinite(loss).all()
    assert torch.allclose(loss[1], (pred[1, :4] - target[1, :4]).square().mean())
    assert torch.allclose(loss[0], (pred[0] - target[0]).square().mean())
    with pytest.raises(MotionDataError):
        masked_mse(pred, target, mask[:, :3])


def test_ddim_path_matches_sampler_and_carries_gradients() -> None:
    weight = torch.nn.Parameter(torch.eye(D) * 0.5)

    def model_fn(x_t: Tensor, t: Tensor, *, uncond: bool = False) -> Tensor:
        return torch.tanh(x_t @ weight)

    x_start = torch.randn(B, T, D, generator=gen(22))
    noise = torch.randn(B, T, D, generator=gen(23))
    spaced = NoiseSchedule.cosine().respace(20)
    x_k = q_sample(spaced, x_start, torch.full((B,), 5), noise).requires_grad_(True)
    preds = ddim_path(model_fn, x_k, 6)
    assert len(preds) == 6
    steps, on_step = recorder()
    ddim_sample(model_fn, (B, T, D), start_step=6, x_start=x_start, noise=noise, progress=on_step)
    for pred, step in zip(preds, steps, strict=True):
        assert torch.allclose(pred.detach(), step.pred_x0, atol=1e-6)
    grad_x = torch.autograd.grad(preds[-1].sum(), x_k, retain_graph=True)[0]
    assert grad_x.abs().sum() > 0  # the last prediction depends on x_K only through the five earlier steps
    loss = sum((p - x_start).square().mean() for p in preds)
    loss.backward()
    assert weight.grad is not None and weight.grad.abs().sum() > 0


def test_skip_x0_is_the_wiener_estimate_and_removes_off_data_noise() -> None:
    """Unit prior: sqrt(ab) x_t; a prior with zero variance along a direction: that direction of x_t is dropped;
    and over many draws the covariance skip is the least-squares linear estimate of x0 (zero residual)."""
    schedule = NoiseSchedule.cosine()
    g = torch.Generator().manual_seed(0)
    t = torch.tensor([300, 300])
    x_t = torch.randn(B, T, D, generator=g, dtype=torch.float64)
    zero = torch.zeros_like(x_t)
    ab = schedule.alphas_cumprod[300]
    assert torch.allclose(skip_x0(schedule, x_t, t, zero), ab.sqrt() * x_t)
    basis = torch.linalg.qr(torch.randn(D, D, generator=g, dtype=torch.float64))[0]
    var = torch.tensor([0.0, 0.5, 1.0, 2.0, 4.0], dtype=torch.float64)
    out = skip_x0(schedule, x_t, t, zero, basis, var)
    assert torch.allclose((out @ basis)[..., 0], torch.zeros(B, T, dtype=torch.float64), atol=1e-12)
    # data drawn from the prior: the skip's estimate beats any rescaling of it (it is the MMSE linear one)
    x0 = (torch.randn(4000, 1, D, generator=g, dtype=torch.float64) * var.sqrt()) @ basis.T
    tt = torch.full((4000,), 300)
    noisy = q_sample(schedule, x0, tt, torch.randn(x0.shape, generator=g, dtype=torch.float64))
    est = skip_x0(schedule, noisy, tt, torch.zeros_like(noisy), basis, var)
    err = lambda k: (k * est - x0).square().mean().item()  # noqa: E731
    assert err(1.0) < min(err(0.9), err(1.1)) and err(1.0) < (ab.sqrt() * noisy - x0).square().mean().item()
    # the residual enters scaled by sqrt(1 - ab)
    assert torch.allclose(
        skip_x0(schedule, x_t, t, torch.ones_like(x_t)) - skip_x0(schedule, x_t, t, zero),
        (1 - ab).sqrt() * torch.ones_like(x_t),
    )
    # a prior mean m: the estimate is m + the zero-mean estimate from x_t - sqrt(ab) m; at x_t = sqrt(ab) m it is m
    m = torch.randn(B, T, D, generator=g, dtype=torch.float64)
    centred = skip_x0(schedule, x_t, t, zero, basis, var, mean=m)
    assert torch.allclose(centred, m + skip_x0(schedule, x_t - ab.sqrt() * m, t, zero, basis, var))
    assert torch.allclose(skip_x0(schedule, ab.sqrt() * m, t, zero, basis, var, mean=m), m)


def _smooth_motions(n: int, frames: int, dims: int, g: torch.Generator) -> Tensor:
    """Random motions with little power at high temporal frequencies: white noise summed over 8 frames."""
    white = torch.randn(n, frames + 7, dims, generator=g, dtype=torch.float64)
    return white.unfold(1, 8, 1).mean(dim=-1)  # (n, frames, dims)


def test_the_spectral_skip_removes_the_frequencies_motion_lacks() -> None:
    """The DCT is orthonormal; with one prior for every band the spectral skip is the frame-by-frame one; a band
    without variance is removed from x_t; padding keeps the frame-by-frame estimate; on smooth motions (noised) the
    spectral estimate beats the frame-by-frame one, both from the same data."""
    schedule = NoiseSchedule.cosine()
    g = torch.Generator().manual_seed(0)
    dct = dct_matrix(13, torch.float64)
    assert torch.allclose(dct @ dct.T, torch.eye(13, dtype=torch.float64), atol=1e-12)
    basis = torch.linalg.qr(torch.randn(D, D, generator=g, dtype=torch.float64))[0]
    var = torch.tensor([0.1, 0.5, 1.0, 2.0, 4.0], dtype=torch.float64)
    x_t = torch.randn(3, 11, D, generator=g, dtype=torch.float64)
    t, zero = torch.tensor([10, 500, 900]), torch.zeros_like(x_t)
    mask = torch.ones(3, 11, dtype=torch.bool)
    mask[1, 7:] = False
    alike = SpectralPrior(basis.expand(8, D, D).clone(), var.expand(8, D).clone())
    frame = skip_x0(schedule, x_t, t, zero, basis, var)
    assert torch.allclose(skip_x0(schedule, x_t, t, zero, basis, var, spectral=alike, mask=mask), frame, atol=1e-12)
    quiet = SpectralPrior(alike.bases, torch.cat([var.expand(4, D), torch.zeros(4, D, dtype=torch.float64)]))
    out = skip_x0(schedule, x_t, t, zero, basis, var, spectral=quiet, mask=mask)
    coeffs = dct_matrix(11, torch.float64) @ out[0]
    assert coeffs[6:].abs().max() < 1e-12 and coeffs[:5].abs().min() > 0  # bands 4-7: frequencies 6-10 of 11
    assert torch.allclose(out[1, 7:], frame[1, 7:])  # padding: the frame-by-frame estimate
    motions = _smooth_motions(400, 48, D, g)
    prior = estimate_spectral_prior(list(motions.numpy()), bands=16)
    frames = motions.reshape(-1, D)
    var_f, basis_f = torch.linalg.eigh(frames.T @ frames / len(frames))
    held = _smooth_motions(200, 40, D, g)
    steps = torch.full((200,), 100)
    noisy = q_sample(schedule, held, steps, torch.randn(held.shape, generator=g, dtype=torch.float64))
    spectral = SpectralPrior(prior.bases.double(), prior.variances.double())
    error = lambda **kw: skip_x0(schedule, noisy, steps, torch.zeros_like(noisy), basis_f, var_f, **kw) - held  # noqa: E731
    assert error(spectral=spectral).square().mean() < 0.7 * error().square().mean()
