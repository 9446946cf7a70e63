"""Gaussian diffusion math for an x0-predicting network: forward noising, posteriors, the training loss.

Every function takes the schedule explicitly and indexes it by the schedule's own step index ``t`` (B,),
which equals the training timestep for an unspaced schedule. Samples are (B, T, D) motion features.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
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
    spectral: SpectralPrior | None = None,
    mask: Tensor | None = None,
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

    ``spectral`` replaces that frame-by-frame prior inside each row's real frames (``mask`` (B, T); all frames
    without it) by a stationary one over time (``SpectralPrior``): noise at frequencies real motion lacks (the
    frame-to-frame shake) is then removed by the skip too, not passed on for the network to cancel.
    """
    ab = extract(schedule.alphas_cumprod, t, x_t)  # (B, 1, 1)
    centred = x_t if mean is None else x_t - ab.sqrt() * mean
    if basis is None or var is None:
        linear = ab.sqrt() * centred
    else:
        basis, var = basis.to(x_t.dtype), var.to(x_t.dtype)
        gain = ab.sqrt() * var / (ab * var + 1.0 - ab)  # (B, 1, D)
        linear = ((centred @ basis) * gain) @ basis.T
        if spectral is not None:
            linear = spectral.estimate(centred, ab, mask, linear)
    if mean is not None:
        linear = linear + mean
    return linear + (1.0 - ab).sqrt() * residual


def dct_matrix(n: int, dtype: torch.dtype = torch.float32) -> Tensor:
    """The orthonormal DCT-II over ``n`` frames, (n, n), row k the frequency k / (2 n) cycles per frame. Orthonormal:
    white noise keeps its variance in every coefficient; a cosine basis: a clip's two ends are not joined (no
    wrap-around edge, unlike the FFT)."""
    k = torch.arange(n, dtype=torch.float64)[:, None]
    frames = torch.arange(n, dtype=torch.float64)[None, :]
    c = torch.cos(torch.pi * (frames + 0.5) * k / n) * (2.0 / n) ** 0.5
    c[0] /= 2.0**0.5
    return c.to(dtype)


@dataclass(frozen=True)
class SpectralPrior:
    """A stationary Gaussian prior over time for (T, D) motions: the DCT-II coefficients at each temporal frequency
    are independent across frequencies, with a feature covariance of their own per frequency band.

    ``bases`` (N, D, D) and ``variances`` (N, D): eigen-decomposition of the second moments of the coefficients of
    band j (frequency j / (2 N) cycles per frame), estimated on N-frame windows (``estimate_spectral_prior``). A
    row of L frames takes, at its frequency k / (2 L), the band nearest it. The estimate of x0 from x_t under it is
    the Wiener filter band by band: sqrt(ab) var / (ab var + 1 - ab) along each band's directions."""

    bases: Tensor
    variances: Tensor

    @property
    def bands(self) -> int:
        return int(self.variances.shape[0])

    def estimate(self, centred: Tensor, ab: Tensor, mask: Tensor | None, fallback: Tensor) -> Tensor:
        """E_lin[x0 - mean | x_t] for ``centred`` = x_t - sqrt(ab) mean (B, T, D), ab (B, 1, 1); frames outside
        ``mask`` keep ``fallback`` (the frame-by-frame estimate). Each row's DCT is over its own real frames."""
        n_rows, n_frames, _ = centred.shape
        device = centred.device
        lengths = torch.full((n_rows,), n_frames, device=device) if mask is None else mask.sum(dim=1).long()
        dct = centred.new_zeros(n_rows, n_frames, n_frames)
        for length in sorted({int(n) for n in lengths.tolist() if n > 0}):
            dct[lengths == length, :length, :length] = dct_matrix(length, centred.dtype).to(device)
        coeffs = dct @ centred  # (B, T, D); zero past each row's length
        k = torch.arange(n_frames, dtype=torch.float64, device=device)[None, :]
        band = torch.round(k * self.bands / lengths.clamp(min=1)[:, None]).clamp(max=self.bands - 1).long()
        band[k.expand(n_rows, -1) >= lengths[:, None]] = -1  # (B, T): each coefficient's band, -1 past the length
        sqrt_ab, one_minus = ab.sqrt().reshape(-1, 1), (1.0 - ab).reshape(-1, 1)  # (B, 1)
        bases, variances = self.bases.to(centred), self.variances.to(centred)
        filtered = torch.zeros_like(coeffs)
        for j in torch.unique(band[band >= 0]).tolist():
            rows, ks = torch.nonzero(band == j, as_tuple=True)
            var = variances[j]
            gain = sqrt_ab[rows] * var / (sqrt_ab[rows] ** 2 * var + one_minus[rows])  # (n, D)
            filtered[rows, ks] = ((coeffs[rows, ks] @ bases[j]) * gain) @ bases[j].T
        inside = (torch.arange(n_frames, device=device)[None, :] < lengths[:, None])[..., None]
        return torch.where(inside, dct.transpose(1, 2) @ filtered, fallback)


def estimate_spectral_prior(motions: Sequence[np.ndarray], bands: int) -> SpectralPrior:
    """``SpectralPrior`` from the (T_i, D) motions' non-overlapping ``bands``-frame windows (shorter clips add
    none): per DCT frequency, the second moments of the coefficients (uncentred, as the frame-by-frame prior)."""
    dct = dct_matrix(bands, torch.float64)
    windows = [
        torch.from_numpy(np.asarray(m[s : s + bands], dtype=np.float64))
        for m in motions
        for s in range(0, len(m) - bands + 1, bands)
    ]
    if not windows:
        raise ValueError(f"no clip has {bands} frames: the spectral prior needs them")
    coeffs = dct @ torch.stack(windows)  # (W, N, D)
    moments = torch.einsum("wnd,wne->nde", coeffs, coeffs) / len(windows)
    var, basis = torch.linalg.eigh(moments)
    return SpectralPrior(basis.float().contiguous(), var.clamp(min=0).float())


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
