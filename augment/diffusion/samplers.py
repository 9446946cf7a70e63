"""Sampling loops wiring a denoiser to a schedule: DDPM ancestral and DDIM, with small hooks.

``steps`` respaces the training schedule as MDM's ``space_timesteps`` does, and the network always receives training
timesteps; ``start_step=n`` noises ``x_start`` to respaced index ``n - 1`` and runs only the last ``n`` steps
(``schedule.start_step_for`` converts a training timestep). The last step returns the x0 prediction itself (exactly
the posterior mean there), which keeps inpainted channels bit-exact. Hooks: ``inpaint`` (channels/frames of every
x0 prediction replaced by a reference, no noise added there; Hu et al. 2024 Eqs. 3-5), ``guidance_scale``
(classifier-free guidance), ``x0_hook`` (``hook(t, x0_hat, x_t) -> x0_hat``: every step's x0 prediction, after
inpainting, goes through it; the methods' sampler callbacks), ``progress`` (per-step callback).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from motionaug.augment.diffusion.gaussian import DenoiseFn, predict_eps_from_x0, q_posterior_mean_variance, q_sample
from motionaug.augment.diffusion.schedule import NoiseSchedule, extract
from motionaug.schemas.errors import MotionDataError


@dataclass(frozen=True)
class InpaintSpec:
    """Which entries of every x0 prediction are forced to a reference motion.

    ``reference`` (B, T, D); ``channels`` an index list or a (D,) bool mask; ``frames`` optional (B, T) or (T,)
    bool mask (default: all frames).
    """

    reference: Tensor
    channels: Sequence[int] | Tensor
    frames: Tensor | None = None

    def mask(self) -> Tensor:
        """(B, T, D) bool: True where the reference replaces the prediction."""
        b, t, d = self.reference.shape
        channels = torch.as_tensor(self.channels)
        if channels.dtype == torch.bool:
            if channels.shape != (d,):
                raise MotionDataError("InpaintSpec", f"channel mask shape {tuple(channels.shape)} != ({d},)")
            chan = channels
        else:
            if channels.numel() and (int(channels.min()) < 0 or int(channels.max()) >= d):
                raise MotionDataError("InpaintSpec", f"channel index outside [0, {d})")
            chan = torch.zeros(d, dtype=torch.bool)
            chan[channels.long()] = True
        frames = torch.ones(b, t, dtype=torch.bool) if self.frames is None else torch.as_tensor(self.frames).bool()
        if frames.ndim == 1:
            frames = frames.expand(b, t)
        if frames.shape != (b, t):
            raise MotionDataError("InpaintSpec", f"frame mask shape {tuple(frames.shape)} != ({b}, {t})")
        chan = chan.to(self.reference.device)
        return frames.to(self.reference.device)[:, :, None] & chan[None, None, :]


X0Hook = Callable[[int, Tensor, Tensor], Tensor]
"""``hook(t, x0_hat, x_t) -> x0_hat``: the training timestep, the step's x0 prediction and its input."""


@dataclass(frozen=True)
class SamplerStep:
    """What the progress callback sees after each step."""

    index: int  # respaced index just denoised (counts down to 0)
    total: int  # steps this call runs
    timestep: int  # training timestep the network saw
    x_t: Tensor  # sample after the step (x_{index-1}; the final sample when index == 0)
    pred_x0: Tensor  # x0 prediction used for the step (after guidance and inpainting)


ProgressFn = Callable[[SamplerStep], None]


def bind_model(model: nn.Module, cond: Tensor | dict[str, Tensor] | None, mask: Tensor | None = None) -> DenoiseFn:
    """A ``DenoiseFn`` calling ``model(x_t, t, cond, mask, force_uncond=uncond)`` (the MDM forward signature).

    The prediction is cast back to x_t's dtype so that a bf16-autocast network leaves the sampler state in fp32.
    """

    def model_fn(x_t: Tensor, t: Tensor, *, uncond: bool = False) -> Tensor:
        return model(x_t, t, cond, mask, force_uncond=uncond).to(x_t.dtype)

    return model_fn


def contrast_guided(primary: DenoiseFn, reference: DenoiseFn, scale: float) -> DenoiseFn:
    """``reference + scale (primary - reference)``: guidance by the contrast of two denoisers.

    Classifier-free guidance contrasts one network with and without its condition; this contrasts two networks (a
    fine-tuned model and the model it was tuned from, each with its own condition), so ``scale > 1`` extrapolates
    along what the fine-tune changed. ``scale == 1`` is ``primary`` alone.
    """

    def model_fn(x_t: Tensor, t: Tensor, *, uncond: bool = False) -> Tensor:
        ref = reference(x_t, t, uncond=uncond)
        return ref + scale * (primary(x_t, t, uncond=uncond) - ref)

    return model_fn


def off_own_motion(direction: Tensor, reference: Tensor, frames: Tensor | None = None) -> Tensor:
    """``direction`` less, channel by channel, its least-squares part along ``reference``'s own motion.

    ``reference``'s motion is each channel minus its mean over the real ``frames`` (B, T bool). Guidance along what
    is left changes posture (the means) and adds motion the reference lacks, but cannot scale the reference's own
    gestures up or down. (B, T, D); padded frames of the result are ``direction``'s.
    """
    weight = torch.ones_like(reference[..., :1]) if frames is None else frames[..., None].to(reference.dtype)
    count = weight.sum(dim=1, keepdim=True).clamp_min(1.0)
    own = (reference - (reference * weight).sum(dim=1, keepdim=True) / count) * weight
    power = (own * own).sum(dim=1, keepdim=True)
    along = (direction * own).sum(dim=1, keepdim=True) / power.clamp_min(1e-8)
    return direction - torch.where(power > 1e-8, along, torch.zeros_like(along)) * own


def guided_x0(model_fn: DenoiseFn, x_t: Tensor, t: Tensor, guidance_scale: float | None) -> Tensor:
    """x0 prediction, with classifier-free guidance x0_u + s (x0_c - x0_u) when a scale is given (MDM cfg_sampler)."""
    x0_cond = model_fn(x_t, t)
    if guidance_scale is None:
        return x0_cond
    x0_uncond = model_fn(x_t, t, uncond=True)
    return x0_uncond + guidance_scale * (x0_cond - x0_uncond)


def _predict_x0(
    model_fn: DenoiseFn,
    schedule: NoiseSchedule,
    x_t: Tensor,
    index: int,
    guidance_scale: float | None,
    inpaint: tuple[Tensor, Tensor] | None,
) -> Tensor:
    """x0_hat at respaced ``index``: guidance, then inpainting (reference overwrites the chosen entries)."""
    t_model = schedule.timesteps[index].expand(x_t.shape[0]).to(x_t.device)
    x0_hat = guided_x0(model_fn, x_t, t_model, guidance_scale)
    if inpaint is not None:
        mask, reference = inpaint
        x0_hat = torch.where(mask, reference, x0_hat)
    return x0_hat


def _noise(
    shape: torch.Size, like: Tensor, generator: torch.Generator | None, inpaint: tuple[Tensor, Tensor] | None
) -> Tensor:
    """Standard normal noise drawn on CPU from ``generator`` (device-independent), zero on inpainted entries."""
    z = torch.randn(shape, generator=generator, dtype=like.dtype).to(like.device)
    if inpaint is not None:
        z = z.masked_fill(inpaint[0], 0.0)
    return z


def ddpm_step(schedule: NoiseSchedule, x_t: Tensor, x0_hat: Tensor, index: int, noise: Tensor | None) -> Tensor:
    """Ancestral step x_{t-1} = posterior mean + sqrt(beta_tilde) z (fixed-small variance; no noise at index 0)."""
    if index == 0:
        return x0_hat
    t = torch.full((x_t.shape[0],), index, dtype=torch.long)
    mean, _, log_variance = q_posterior_mean_variance(schedule, x0_hat, x_t, t)
    return mean if noise is None else mean + torch.exp(0.5 * log_variance) * noise


def ddim_step(
    schedule: NoiseSchedule, x_t: Tensor, x0_hat: Tensor, index: int, eta: float, noise: Tensor | None
) -> Tensor:
    """DDIM update (Song et al. Eq. 12); eta=1 gives sigma^2 = beta_tilde, i.e. the DDPM ancestral step."""
    if index == 0:
        return x0_hat
    t = torch.full((x_t.shape[0],), index, dtype=torch.long)
    eps = predict_eps_from_x0(schedule, x_t, t, x0_hat)
    ab = extract(schedule.alphas_cumprod, t, x_t)
    ab_prev = extract(schedule.alphas_cumprod_prev, t, x_t)
    sigma = eta * ((1 - ab_prev) / (1 - ab)).sqrt() * (1 - ab / ab_prev).sqrt()
    x_prev = ab_prev.sqrt() * x0_hat + (1 - ab_prev - sigma**2).clamp(min=0).sqrt() * eps
    return x_prev if noise is None or eta == 0 else x_prev + sigma * noise


def _respaced(schedule: NoiseSchedule | None, steps: int | str | None) -> NoiseSchedule:
    """The schedule the loop walks: the training one (cosine by default), respaced unless ``steps`` is None or T."""
    base = schedule or NoiseSchedule.cosine()
    return base if steps is None or steps == len(base) else base.respace(steps)


def _inpaint_tensors(
    inpaint: InpaintSpec | None, shape: torch.Size, dtype: torch.dtype, device: torch.device | str
) -> tuple[Tensor, Tensor] | None:
    """(mask, reference) on the sampling device and dtype, or None."""
    if inpaint is None:
        return None
    if inpaint.reference.shape != shape:
        raise MotionDataError(
            "InpaintSpec", f"reference shape {tuple(inpaint.reference.shape)} != sample {tuple(shape)}"
        )
    return inpaint.mask().to(device), inpaint.reference.to(device=device, dtype=dtype)


def _prepare(
    schedule: NoiseSchedule | None,
    steps: int | str | None,
    shape: Sequence[int],
    start_step: int | None,
    x_start: Tensor | None,
    noise: Tensor | None,
    inpaint: InpaintSpec | None,
    generator: torch.Generator | None,
    dtype: torch.dtype,
    device: torch.device | str | None,
) -> tuple[NoiseSchedule, Tensor, int, tuple[Tensor, Tensor] | None]:
    """Respaced schedule, the initial x, the number of steps to run, and the inpainting (mask, reference).

    Initial x: pure noise, or ``q_sample(x_start)`` at index ``start_step - 1``; inpainted entries get no noise,
    so they start on the zero-noise q-path ``sqrt(alpha_bar) * reference``. ``device`` None: ``x_start``'s, else
    CPU. Noise is drawn on CPU from ``generator`` and moved, so a seed gives the same noise on every device.
    """
    sched, shape = _respaced(schedule, steps), torch.Size(shape)
    if device is None:
        device = x_start.device if x_start is not None else torch.device("cpu")
    inpaint_t = _inpaint_tensors(inpaint, shape, dtype, device)
    n_run = len(sched) if start_step is None else int(start_step)
    if not 1 <= n_run <= len(sched):
        raise MotionDataError("sampler", f"start_step {start_step} outside [1, {len(sched)}]")
    if start_step is not None and x_start is None:
        raise MotionDataError("sampler", "start_step needs x_start (the clean motion to noise)")
    for name, given in (("noise", noise), ("x_start", x_start)):
        if given is not None and given.shape != shape:
            raise MotionDataError("sampler", f"{name} shape {tuple(given.shape)} != {tuple(shape)}")
    if noise is None:
        noise = torch.randn(shape, generator=generator, dtype=dtype)
    noise = noise.to(device=device, dtype=dtype)
    if inpaint_t is not None:
        noise = noise.masked_fill(inpaint_t[0], 0.0)
    if x_start is None and inpaint_t is None:
        return sched, noise, n_run, None
    t0 = torch.full((shape[0],), n_run - 1, dtype=torch.long)
    if x_start is None:  # pure noise except the inpainted entries
        return sched, torch.where(inpaint_t[0], q_sample(sched, inpaint_t[1], t0, noise), noise), n_run, inpaint_t
    x0 = x_start.to(device=device, dtype=dtype)
    if inpaint_t is not None:
        x0 = torch.where(inpaint_t[0], inpaint_t[1], x0)
    return sched, q_sample(sched, x0, t0, noise), n_run, inpaint_t


def _loop(
    model_fn: DenoiseFn,
    sched: NoiseSchedule,
    x: Tensor,
    n_run: int,
    update: Callable[[Tensor, Tensor, int, torch.Generator | None], Tensor],
    guidance_scale: float | None,
    inpaint_t: tuple[Tensor, Tensor] | None,
    progress: ProgressFn | None,
    generator: torch.Generator | None,
    x0_hook: X0Hook | None = None,
) -> Tensor:
    """The shared reverse loop: predict x0 at each index n_run-1..0 (through ``x0_hook``), then apply ``update``."""
    for index in range(n_run - 1, -1, -1):
        x0_hat = _predict_x0(model_fn, sched, x, index, guidance_scale, inpaint_t)
        if x0_hook is not None:
            x0_hat = x0_hook(int(sched.timesteps[index]), x0_hat, x)
        x = update(x, x0_hat, index, generator)
        if progress is not None:
            progress(SamplerStep(index, n_run, int(sched.timesteps[index]), x, x0_hat))
    return x


@torch.no_grad()
def ddpm_sample(
    model_fn: DenoiseFn,
    shape: Sequence[int],
    *,
    schedule: NoiseSchedule | None = None,
    steps: int | str | None = None,
    start_step: int | None = None,
    x_start: Tensor | None = None,
    noise: Tensor | None = None,
    inpaint: InpaintSpec | None = None,
    guidance_scale: float | None = None,
    progress: ProgressFn | None = None,
    generator: torch.Generator | None = None,
    dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
    x0_hook: X0Hook | None = None,
) -> Tensor:
    """DDPM ancestral sampling (fixed-small variance), all 1000 steps unless ``steps`` respaces. Returns (B, T, D)."""
    sched, x, n_run, inpaint_t = _prepare(
        schedule, steps, shape, start_step, x_start, noise, inpaint, generator, dtype, device
    )

    def update(x_t: Tensor, x0_hat: Tensor, index: int, gen: torch.Generator | None) -> Tensor:
        z = _noise(x_t.shape, x_t, gen, inpaint_t) if index > 0 else None
        return ddpm_step(sched, x_t, x0_hat, index, z)

    return _loop(model_fn, sched, x, n_run, update, guidance_scale, inpaint_t, progress, generator, x0_hook)


@torch.no_grad()
def ddim_sample(
    model_fn: DenoiseFn,
    shape: Sequence[int],
    *,
    steps: int | str | None = 20,
    eta: float = 0.0,
    schedule: NoiseSchedule | None = None,
    start_step: int | None = None,
    x_start: Tensor | None = None,
    noise: Tensor | None = None,
    inpaint: InpaintSpec | None = None,
    guidance_scale: float | None = None,
    progress: ProgressFn | None = None,
    generator: torch.Generator | None = None,
    dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
    x0_hook: X0Hook | None = None,
) -> Tensor:
    """DDIM sampling over ``steps`` respaced timesteps (eta=0: deterministic given the initial noise).

    Returns (B, T, D).
    """
    sched, x, n_run, inpaint_t = _prepare(
        schedule, steps, shape, start_step, x_start, noise, inpaint, generator, dtype, device
    )

    def update(x_t: Tensor, x0_hat: Tensor, index: int, gen: torch.Generator | None) -> Tensor:
        z = _noise(x_t.shape, x_t, gen, inpaint_t) if index > 0 and eta > 0 else None
        return ddim_step(sched, x_t, x0_hat, index, eta, z)

    return _loop(model_fn, sched, x, n_run, update, guidance_scale, inpaint_t, progress, generator, x0_hook)


def ddim_path(
    model_fn: DenoiseFn,
    x_k: Tensor,
    steps_from_k: int,
    *,
    steps: int | str | None = 20,
    schedule: NoiseSchedule | None = None,
    inpaint: InpaintSpec | None = None,
    guidance_scale: float | None = None,
) -> list[Tensor]:
    """x0 predictions along the deterministic DDIM path from ``x_k`` (at respaced index ``steps_from_k - 1``) to 0.

    Runs with autograd on (nothing detached), so a loss on any or all predictions backpropagates through every
    step of the path (style fine-tuning's L_rec). ``x_k`` is typically ``q_sample`` of a motion at that index.
    Returns ``steps_from_k`` tensors (B, T, D), the last one being the final sample.
    """
    sched = _respaced(schedule, steps)
    if not 1 <= steps_from_k <= len(sched):
        raise MotionDataError("ddim_path", f"steps_from_k {steps_from_k} outside [1, {len(sched)}]")
    inpaint_t = _inpaint_tensors(inpaint, x_k.shape, x_k.dtype, x_k.device)
    x, preds = x_k, []
    for index in range(steps_from_k - 1, -1, -1):
        x0_hat = _predict_x0(model_fn, sched, x, index, guidance_scale, inpaint_t)
        preds.append(x0_hat)
        x = ddim_step(sched, x, x0_hat, index, 0.0, None)
    return preds
