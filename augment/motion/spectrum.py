"""Motion signals over time in frequency bands: power per band and a ceiling on it taken from reference motions.

Frequencies come from the orthonormal DCT-II over a clip's own frames (``augment.diffusion.dct_matrix``):
coefficient k of an L-frame clip sits at k / (2 L) cycles per frame, so clips of different lengths share bands,
and white noise has the same power per coefficient whatever the length (the band power is a mean, not a sum).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from motionaug.augment.diffusion import dct_matrix


def band_of_coefficients(frames: int, bands: int) -> Tensor:
    """(frames,) the band of each DCT coefficient: ``bands`` equal bands over 0 to 0.5 cycles per frame."""
    return (torch.arange(frames) * bands // frames).clamp(max=bands - 1)


def band_power(x: Tensor, bands: int) -> Tensor:
    """(bands, C) mean squared DCT coefficient of each channel of ``x`` (T, C) per band (0 where a band has no
    coefficient: clips shorter than ``bands`` frames)."""
    return _band_means(dct_matrix(x.shape[0], torch.float64) @ x.double(), bands)


def _band_means(coeffs: Tensor, bands: int) -> Tensor:
    band = band_of_coefficients(coeffs.shape[0], bands)
    total = torch.zeros(bands, coeffs.shape[1], dtype=torch.float64).index_add_(0, band, coeffs.square())
    count = torch.bincount(band, minlength=bands).clamp(min=1).to(torch.float64)
    return total / count[:, None]


def spectral_ceiling(x: Tensor, references: Sequence[Tensor], bands: int, from_band: int, slack: float = 1.0) -> Tensor:
    """``x`` (T, C) with each channel's power in every band from ``from_band`` up scaled down, where it exceeds
    it, to ``slack``^2 times the largest power of that channel and band among ``references`` (T_i, C) (a band's
    coefficients keep their signs and ratios: attenuation only, no phase change). Lower bands are untouched.

    Why: a generated motion that shakes from frame to frame has power at frequencies where the motions it was
    made from have little; a fixed low-pass (a Gaussian over time) also takes the fast parts the references do
    have (a strut's accents, a kick), a ceiling per band and channel keeps those."""
    if not references:
        raise ValueError("spectral_ceiling needs at least one reference motion")
    if slack <= 0:
        raise ValueError(f"slack must be > 0, got {slack}")
    allowed = torch.stack([band_power(r, bands) for r in references]).amax(dim=0) * slack**2  # (bands, C)
    dct = dct_matrix(x.shape[0], torch.float64)
    coeffs = dct @ x.double()
    power = _band_means(coeffs, bands)
    gain = torch.where(power > allowed, (allowed / power.clamp(min=1e-30)).sqrt(), torch.ones_like(power))
    gain[:from_band] = 1.0
    coeffs = coeffs * gain[band_of_coefficients(x.shape[0], bands)]
    return (dct.T @ coeffs).to(x.dtype)
