"""The lab's UMSD hooks (``lab/umsd_hooks.py``) on arrays: what each does, and that they register by name."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lab.umsd_hooks import SpectralCeiling, X0Smooth, masked_smooth
from motionaug.augment.methods.common import feet_channels
from motionaug.augment.methods.hooks import (
    LossBatch,
    SamplerStep,
    ShapeContext,
    loss_terms,
    output_shapers,
    sampler_callbacks,
)
from motionaug.augment.motion.spectrum import band_power


def test_the_hooks_register_by_name() -> None:
    assert isinstance(sampler_callbacks.create({"name": "x0_smooth", "sigma": 1.0}), X0Smooth)
    assert {"spectral_ceiling", "smooth", "moments"} <= set(output_shapers.names())


def test_the_step_smoothing_sees_only_each_rows_own_frames() -> None:
    x = torch.randn(2, 30, 263)
    mask = torch.ones(2, 30, dtype=torch.bool)
    mask[1, 20:] = False
    signal = [c for c in range(263) if c not in set(feet_channels())]
    smooth = masked_smooth(x, mask, 1.5, signal)
    alone = masked_smooth(x[1:, :20], mask[1:, :20], 1.5, signal)
    torch.testing.assert_close(smooth[1:, :20], alone)  # the padding does not leak in
    torch.testing.assert_close(smooth[..., feet_channels()], x[..., feet_channels()])
    assert (smooth[0, 1:-1, signal].diff(dim=0).abs().mean() < 0.5 * x[0, :, signal].diff(dim=0).abs().mean()).item()
    callback = X0Smooth(1.5, from_t=500)
    torch.testing.assert_close(callback(SamplerStep(600, x, x, mask)), smooth)
    assert callback(SamplerStep(400, x, x, mask)) is x  # below from_t: untouched


def test_smoothing_removes_frame_jitter_but_not_the_motion_or_the_contacts() -> None:
    frames = np.arange(120)
    motion = np.zeros((120, 263), np.float32)
    motion[:, 3:259] = np.sin(2 * np.pi * frames / 80)[:, None]  # a 0.25 Hz gesture at 20 fps
    jitter = np.where(frames % 2 == 0, 0.05, -0.05)[:, None]  # frame-to-frame alternation
    motion[:, 259:] = (frames % 10 < 5)[:, None]  # contacts: 0/1 labels
    noisy = motion.copy()
    noisy[:, :259] += jitter
    context = ShapeContext(motion, motion, None, 20.0)
    smooth = output_shapers.create({"name": "smooth", "sigma": 1.5})
    assert output_shapers.create({"name": "smooth", "sigma": 0.0})(noisy, context) is noisy
    out = smooth(noisy, context)
    np.testing.assert_array_equal(out[:, 259:], motion[:, 259:])
    inner = slice(10, -10)  # away from the clip's edges
    assert np.abs(out[inner, :259] - motion[inner, :259]).max() < 0.01  # jitter gone, the gesture kept
    assert np.abs(noisy[inner, :259] - motion[inner, :259]).max() > 0.04


def test_the_spectral_ceiling_caps_power_above_its_frequency_only() -> None:
    rng = np.random.default_rng(0)
    frames = np.arange(96)
    calm = (np.sin(2 * np.pi * frames / 48)[:, None] * np.ones((1, 263))).astype(np.float32)
    output = calm + 0.3 * rng.normal(size=(96, 263)).astype(np.float32)  # jitter neither reference has
    context = ShapeContext(calm, calm, None, 20.0)
    capped = SpectralCeiling(1.0, 2.5)(output, context)
    signal = [c for c in range(263) if c not in set(feet_channels())]
    bands, from_band = 16, 4  # 2.5 Hz at 20 fps in bands of 0.625 Hz

    def power(motion: np.ndarray) -> torch.Tensor:
        return band_power(torch.from_numpy(motion[:, signal]).double(), bands)

    ceiling = torch.maximum(power(calm), power(calm))
    assert (power(capped)[from_band:] <= ceiling[from_band:] * (1 + 1e-4) + 1e-8).all()
    assert (power(output)[from_band:] > ceiling[from_band:] * 1.01).any()  # there was something to cut
    torch.testing.assert_close(power(capped)[:from_band], power(output)[:from_band], rtol=1e-3, atol=1e-6)
    np.testing.assert_array_equal(capped[:, feet_channels()], output[:, feet_channels()])
    assert SpectralCeiling(0.0)(output, context) is output


def test_the_acceleration_term_charges_frame_to_frame_shake_not_a_smooth_offset() -> None:
    fps, frames, shake = 20.0, 30, 0.01  # metres
    mask = torch.ones(2, frames, dtype=torch.bool)
    mask[1, 20:] = False  # a padded row
    target = torch.randn(2, frames, 22, 3).cumsum(dim=1) * 0.01
    sign = (-1.0) ** torch.arange(frames)
    shaken = target + shake * sign[None, :, None, None]
    offset = target + torch.linspace(0, 0.2, frames)[None, :, None, None]  # a steady drift: no acceleration
    term = loss_terms.create({"name": "acceleration", "weight": 0.1})
    assert term.weight == 0.1
    assert term(LossBatch(offset, target, mask, fps)).item() < 1e-4
    assert term(LossBatch(shaken, target, mask, fps)).item() == pytest.approx(4 * shake * fps**2, rel=1e-4)
    padded = shaken.clone()
    padded[1, 20:] += 5.0  # whatever the padding holds costs nothing
    assert term(LossBatch(padded, target, mask, fps)).item() == pytest.approx(4 * shake * fps**2, rel=1e-4)
