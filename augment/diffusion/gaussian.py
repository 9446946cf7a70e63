"""Gaussian diffusion math for an x0-predicting network: forward noising, posteriors, the training loss.

Every function takes the schedule explicitly and indexes it by the schedule's own step index ``t`` (B,),
which equals the training timestep for an unspaced schedule. Samples are (B, T, D) motion features.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import torch
from torch import Tensor

from motionaug.augment.diffusion.schedule import NoiseSchedule, extract
from motionaug.schemas.errors import MotionDataError


class DenoiseFn(Protocol):
    """A network bound to its condition and frame mask: ``x_t (B,T,D), t (B,) training timesteps -> x0_hat``.

    ``uncond=True`` asks for the condition-dropped prediction (classifier-free guidance).
    """

    def __call__(self, x_t: Tensor, t: Tensor, *, uncond: bool = False) -> Tensor: ...


@dataclass(frozen=True)
class PMeanVar:
    """p(x_{t-1} | x_t) from an x0 prediction: the posterior at x0_hat with fixed-small variance (MDM)."""

    mean: Tensor
    variance: Tensor
    log_variance: Tensor
    pred_x0: Tensor


def q_sample(schedule: NoiseSchedule, x0: Tensor, t: Tensor, noise: Tensor) -> Tensor:
    """x_t ~ q(x_t | x_0) = sqrt(alpha_bar_t) x0 + sqrt(1 - alpha_bar_t) noise."""
    if noise.shape != x0.shape:
        raise MotionDataError("q_sample", f"noise shape {tuple(noise.shape)} != x0 shape {tuple(x0.shape)}")
    return (
        extract(schedule.sqrt_alphas_cumprod, t, x0) * x0
        + extract(schedule.sqrt_one_minus_alphas_cumprod, t, x0) * noise
    )


def skip_x0(
    schedule: NoiseSchedule,
    x_t: Tensor,
    t: Tensor,
    residual: Tensor,
    basis: Tensor | None = None,
    var: Tensor | None = None,
    mean: Tensor | None = None,
) -> Tensor:
    """x0_hat = E_lin[x0 | x_t] + sqrt(1 - alpha_bar_t) F: a network output F read as the residual to the best
    linear (Wiener) estimate of x0 from x_t under a Gaussian data prior with covariance basis diag(var) basis^T
    (and mean ``mean``, shaped like x_t; zero without it).

    Without ``basis``/``var`` the prior is unit variance and the estimate is sqrt(alpha_bar_t) x_t (the c_skip /
    c_out preconditioning of Karras et al. 2022 for a VP process, sigma_data = 1). With the data's covariance the
    estimate passes x_t through only where the data vary: per principal direction the gain is
    sqrt(ab) var / (ab var + 1 - ab), so noise along directions the data never take is removed by the skip itself
    and the residual left to F lies in the data's few principal directions. Why a skip at all: identity at small t
    need not be learnt through a network narrower than the features. x_t (B, T, D), t (B,), basis (D, D) columns
    = directions, var (D,).
    """
    ab = extract(schedule.alphas_cumprod, t, x_t)  # (B, 1, 1)
    centred = x_t if mean is None else x_t - ab.sqrt() * mean
    if basis is None or var is None:
        linear = ab.sqrt() * centred
    else:
        basis, var = basis.to(x_t.dtype), var.to(x_t.dtype)
        gain = ab.sqrt() * var / (ab * var + 1.0 - ab)  # (B, 1, D)
        linear = ((centred @ basis) * gain) @ basis.T
    if mean is not None:
        linear = linear + mean
    return linear + (1.0 - ab).sqrt() * residual


def q_mean_variance(schedule: NoiseSchedule, x0: Tensor, t: Tensor) -> tuple[Tensor, Tensor]:
    """Mean and variance of q(x_t | x_0) (variance broadcast-shaped (B, 1, 1))."""
    return extract(schedule.sqrt_alphas_cumprod, t, x0) * x0, extract(1.0 - schedule.alphas_cumprod, t, x0)


def q_posterior_mean_variance(
    schedule: NoiseSchedule, x0: Tensor, x_t: Tensor, t: Tensor
) -> tuple[Tensor, Tensor, Tensor]:
    """Mean, variance and clipped log-variance of q(x_{t-1} | x_t, x_0)."""
    mean = extract(schedule.posterior_mean_coef1, t, x_t) * x0 + extract(schedule.posterior_mean_coef2, t, x_t) * x_t
    variance = extract(schedule.posterior_variance, t, x_t)
    log_variance = extract(schedule.posterior_log_variance_clipped, t, x_t)
    return mean, variance, log_variance


def p_mean_variance(schedule: NoiseSchedule, x0_hat: Tensor, x_t: Tensor, t: Tensor) -> PMeanVar:
    """The model's reverse step given its x0 prediction (x0-parameterisation: the posterior at x0_hat)."""
    mean, variance, log_variance = q_posterior_mean_variance(schedule, x0_hat, x_t, t)
    return PMeanVar(mean, variance, log_variance, x0_hat)


def predict_eps_from_x0(schedule: NoiseSchedule, x_t: Tensor, t: Tensor, x0: Tensor) -> Tensor:
    """The noise implied by x_t and an x0 estimate: (x_t / sqrt(ab) - x0) / sqrt(1/ab - 1)."""
    return (extract(schedule.sqrt_recip_alphas_cumprod, t, x_t) * x_t - x0) / extract(
        schedule.sqrt_recipm1_alphas_cumprod, t, x_t
    )


def masked_mse(pred: Tensor, target: Tensor, mask: Tensor | None) -> Tensor:
    """Per-sample MSE over valid frames only, (B,). ``mask`` (B, T) bool, True = real frame.

    Padding is selected away with ``where`` (not multiplied by 0), so even NaN/inf padding cannot leak in.
    """
    if pred.shape != target.shape:
        raise MotionDataError("masked_mse", f"prediction {tuple(pred.shape)} != target {tuple(target.shape)}")
    if mask is None:
        return (pred - target).square().mean(dim=(1, 2))
    if mask.shape != pred.shape[:2]:
        raise MotionDataError("masked_mse", f"mask {tuple(mask.shape)} != (B, T) {tuple(pred.shape[:2])}")
    keep = mask[..., None]  # (B, T, 1)
    sq = torch.where(keep, pred - target, torch.zeros((), dtype=pred.dtype, device=pred.device)).square()
    counts = mask.sum(dim=1).clamp(min=1) * pred.shape[2]
    return sq.sum(dim=(1, 2)) / counts


def sample_timesteps(batch: int, schedule: NoiseSchedule, generator: torch.Generator | None = None) -> Tensor:
    """Uniform training timesteps (B,) (MDM's UniformSampler)."""
    return torch.randint(0, len(schedule), (batch,), generator=generator)


def x0_training_loss(
    model_fn: DenoiseFn,
    schedule: NoiseSchedule,
    x0: Tensor,
    mask: Tensor | None,
    t: Tensor | None = None,
    noise: Tensor | None = None,
    generator: torch.Generator | None = None,
) -> Tensor:
    """MDM's simple loss: noise x0 to a random t, predict x0, masked MSE averaged over the batch (scalar).

    Padded frames never enter the loss; they are zeroed before noising so they cannot carry NaN into the net.
    """
    if t is None:
        t = sample_timesteps(x0.shape[0], schedule, generator).to(x0.device)
    if noise is None:
        noise = torch.randn(x0.shape, generator=generator, dtype=x0.dtype).to(x0.device)
    if mask is not None:
        x0_clean = torch.where(mask[..., None], x0, torch.zeros((), dtype=x0.dtype, device=x0.device))
    else:
        x0_clean = x0
    x_t = q_sample(schedule, x0_clean, t, noise)
    x0_hat = model_fn(x_t, schedule.timesteps.to(t.device)[t])
    return masked_mse(x0_hat, x0, mask).mean()
