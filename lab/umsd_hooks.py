"""UMSD clean-ups under study, as hooks a run config names (``hooks.modules: [lab.umsd_hooks]``).

- sampler callback ``x0_smooth`` (``sigma``, ``from_t``): every step's x0 prediction at timesteps >= ``from_t``
  Gaussian-filtered over time within each row's frames, but the foot contacts; the shake of early predictions is
  not fed back by the later steps.
- output shaper ``spectral_ceiling`` (``slack``, ``from_hz``): each generated channel's power per frequency band
  from ``from_hz`` up capped at slack^2 times the larger of the content's and the style example's.
- output shaper ``smooth`` (``sigma``): every channel but the foot contacts Gaussian-filtered over time.
- loss term ``acceleration`` (``weight``): L1 on joint accelerations, m/s^2: x0 predictions right on average but
  shaking from frame to frame pay for the shake, which costs little in L_pos and L_vel.

``lab/umsd_rescore.py`` applies the shapers to saved outputs without sampling again.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from motionaug.augment.methods.common import feet_channels
from motionaug.augment.methods.hooks import (
    LossBatch,
    LossTerm,
    OutputShaper,
    SamplerCallback,
    SamplerStep,
    ShapeContext,
    loss_terms,
    output_shapers,
    sampler_callbacks,
)
from motionaug.augment.motion.kinematics import gaussian_smooth_time
from motionaug.augment.motion.spectrum import spectral_ceiling
from motionaug.schemas.skeleton import T2M

CEILING_BANDS = 16  # frequency bands of the ceiling: fps / 32 Hz wide (0.625 Hz at 20 fps)


def signal_channels(n_feats: int = T2M.feature_dim) -> list[int]:
    """Every channel but the foot contacts (labels, not signals): what smoothing over time may touch."""
    feet = set(feet_channels())
    return [c for c in range(n_feats) if c not in feet]


def masked_smooth(x: torch.Tensor, mask: torch.Tensor, sigma: float, channels: Sequence[int]) -> torch.Tensor:
    """(B, T, F) ``x`` with ``channels`` Gaussian-filtered over time within each row's valid frames (``mask``
    (B, T), valid first): each row's last valid frame stands in for its padding, so a row's result does not depend
    on its batch mates."""
    last = (mask.sum(dim=1, keepdim=True) - 1).clamp(min=0)
    frames = torch.minimum(torch.arange(x.shape[1], device=x.device)[None], last)  # (B, T)
    cols = list(channels)
    extended = torch.gather(x[..., cols], 1, frames[..., None].expand(-1, -1, len(cols)))
    out = x.clone()
    out[..., cols] = torch.where(mask[..., None], gaussian_smooth_time(extended, sigma, time_dim=1), x[..., cols])
    return out


@sampler_callbacks.register("x0_smooth")
class X0Smooth(SamplerCallback):
    def __init__(self, sigma: float, from_t: int = 0) -> None:
        self.sigma, self.from_t = sigma, from_t

    def __call__(self, step: SamplerStep) -> torch.Tensor:
        if self.sigma <= 0 or step.t < self.from_t:
            return step.x0
        return masked_smooth(step.x0, step.mask, self.sigma, signal_channels(step.x0.shape[-1]))


@output_shapers.register("spectral_ceiling")
class SpectralCeiling(OutputShaper):
    def __init__(self, slack: float, from_hz: float = 2.5) -> None:
        self.slack, self.from_hz = slack, from_hz

    def __call__(self, output: np.ndarray, context: ShapeContext) -> np.ndarray:
        if self.slack <= 0:
            return output
        from_band = min(CEILING_BANDS, int(np.ceil(self.from_hz / (context.fps / 2.0 / CEILING_BANDS) - 1e-9)))
        references = [torch.from_numpy(context.content), torch.from_numpy(context.example)]
        capped = spectral_ceiling(torch.from_numpy(output), references, CEILING_BANDS, from_band, self.slack)
        out = capped.numpy().astype(np.float32)
        out[:, feet_channels()] = output[:, feet_channels()]
        return out


@output_shapers.register("smooth")
class Smooth(OutputShaper):
    def __init__(self, sigma: float) -> None:
        self.sigma = sigma

    def __call__(self, output: np.ndarray, context: ShapeContext) -> np.ndarray:
        if self.sigma <= 0:
            return output
        signal = signal_channels(output.shape[1])
        out = output.copy()
        out[:, signal] = gaussian_smooth_time(torch.from_numpy(output[:, signal]), self.sigma, time_dim=0).numpy()
        return out


def acceleration_l1(predicted: torch.Tensor, target: torch.Tensor, mask: torch.Tensor, fps: float) -> torch.Tensor:
    """L1 between the joint accelerations (m/s^2) of two joint sequences (B, T, J, 3), over the frames whose two
    neighbours are real. A shake of +-e metres alternating frame to frame costs 4e fps^2 here."""

    def acceleration(x: torch.Tensor) -> torch.Tensor:
        velocity = (x[:, 1:] - x[:, :-1]) * fps
        return (velocity[:, 1:] - velocity[:, :-1]) * fps

    triple = (mask[:, 2:] & mask[:, 1:-1] & mask[:, :-2])[..., None, None].float()
    acc = acceleration(predicted) - acceleration(target)
    return (acc.abs() * triple).sum() / (triple.sum() * acc.shape[2] * 3).clamp(min=1)


@loss_terms.register("acceleration")
class Acceleration(LossTerm):
    def __call__(self, batch: LossBatch) -> torch.Tensor:
        return acceleration_l1(batch.predicted, batch.target, batch.mask, batch.fps)
