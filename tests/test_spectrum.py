"""The spectral ceiling (augment.motion.spectrum): jitter above what the references have goes, their fast parts stay."""

from __future__ import annotations

import pytest
import torch

from motionaug.augment.diffusion import dct_matrix
from motionaug.augment.motion.kinematics import gaussian_smooth_time
from motionaug.augment.motion.spectrum import band_of_coefficients, band_power, spectral_ceiling

FRAMES = 120
BANDS = 16


def _waves(*periods: float) -> torch.Tensor:
    """(FRAMES, len(periods)) one sine per channel, period in frames."""
    t = torch.arange(FRAMES, dtype=torch.float64)
    return torch.stack([torch.sin(2 * torch.pi * t / p) for p in periods], dim=1)


def test_bands_split_half_the_frame_rate_evenly_for_any_length() -> None:
    for frames in (16, 40, 121):
        band = band_of_coefficients(frames, BANDS)
        assert band[0] == 0 and band[-1] == BANDS - 1 and (band.diff() >= 0).all()
        assert torch.bincount(band, minlength=BANDS).min() >= 1
    # white noise has the same power per band whatever the clip's length (a mean, not a sum)
    g = torch.Generator().manual_seed(0)
    for frames in (64, 400):
        power = band_power(torch.randn(frames, 200, generator=g, dtype=torch.float64), BANDS).mean(dim=1)
        assert torch.allclose(power, torch.ones(BANDS, dtype=torch.float64), atol=0.25)


def test_the_ceiling_removes_jitter_the_references_lack_and_leaves_low_bands_alone() -> None:
    clean = _waves(40, 30)
    g = torch.Generator().manual_seed(0)
    noisy = clean + 0.2 * torch.randn(FRAMES, 2, generator=g, dtype=torch.float64)
    out = spectral_ceiling(noisy, [clean], BANDS, from_band=3)
    assert (out - clean).square().mean() < (noisy - clean).square().mean() / 3  # 3 of 16 bands keep noise
    low = band_of_coefficients(FRAMES, BANDS) < 3
    dct = dct_matrix(FRAMES, torch.float64)
    torch.testing.assert_close((dct @ out)[low], (dct @ noisy)[low])  # untouched below from_band
    assert (band_power(out, BANDS)[3:] <= band_power(clean, BANDS)[3:] * (1 + 1e-9) + 1e-12).all()


def test_a_motion_under_the_ceiling_is_unchanged_and_a_reference_s_fast_part_is_kept() -> None:
    slow = _waves(40, 40)
    torch.testing.assert_close(spectral_ceiling(slow, [slow], BANDS, from_band=2), slow)
    fast = slow + 0.3 * _waves(3, 3)  # 6.7 Hz accents at 20 fps, which a reference has
    g = torch.Generator().manual_seed(1)
    noisy = fast + 0.05 * torch.randn(FRAMES, 2, generator=g, dtype=torch.float64)
    out = spectral_ceiling(noisy, [slow, fast], BANDS, from_band=2)
    blurred = gaussian_smooth_time(noisy, 1.0, time_dim=0)  # a low-pass takes the accents too
    assert (out - fast).square().mean() < (blurred - fast).square().mean() / 5


def test_the_ceiling_rejects_no_reference_and_a_bad_slack() -> None:
    with pytest.raises(ValueError, match="at least one reference"):
        spectral_ceiling(_waves(40), [], BANDS, 2)
    with pytest.raises(ValueError, match="slack must be > 0"):
        spectral_ceiling(_waves(40), [_waves(40)], BANDS, 2, slack=0.0)
