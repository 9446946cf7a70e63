"""Spectral style transfer as an output shaper: the example's timing texture, not only its posture and amplitude.

- output shaper ``spectrum`` (``bands``, ``most``, ``keep_power``): each channel's power per frequency band is
  scaled by the style example's power in that band over its reference's (the plain pool clip standing in for the
  example's content), then the channel is brought back to its own total power. The content keeps its phases (when
  things happen) and its amplitude; what changes is how its motion is spread over slow and fast frequencies: a
  shuffle's damped accents, a strut's sharp ones.

Why: the moment rule (``motionaug.augment.methods.shapers``) carries a style's mean posture and variance, which a
clip-standardised judge cannot see; styles also differ in the shape of each joint's motion over time. Fourier
methods carry that shape from one motion to another: Unuma, Anjyo and Takeuchi, "Fourier principles for
emotion-based human figure animation" (SIGGRAPH 1995), interpolate Fourier coefficients between an emotional and a
neutral gait; Yumer and Mitra, "Spectral style transfer for human motion between independent actions" (SIGGRAPH
2016), add the style's magnitude difference, taken between a styled and a neutral take of one action, to a
different action's spectrum and keep that action's phase. This shaper is the second in the product's frequency
bands (``augment.motion.spectrum``: DCT-II over the clip's frames), as a ratio per band so that it is independent
of the clip's length, with the total power kept so that it composes with ``moments`` (amplitude).

Control row: ``bench/bench_lso.py run --row shapers --shapers spectrum`` (the shaper on the content clip, no
network), as ``--row moments`` is the moment rule's.
"""

from __future__ import annotations

import numpy as np
import torch

from motionaug.augment.diffusion import dct_matrix
from motionaug.augment.methods.hooks import OutputShaper, ShapeContext, output_shapers
from motionaug.augment.motion.features import feature_slices
from motionaug.augment.motion.spectrum import band_of_coefficients, band_power
from motionaug.schemas.skeleton import T2M


def shaped_channels() -> np.ndarray:
    """Root height, pose and joint velocity channels: what the moment rule's amplitude touches (the root's path
    and the foot contacts stay the content's)."""
    slices = feature_slices(T2M)
    return np.r_[slices["root_y"], slices["ric"], slices["rot"], slices["local_vel"]]


def spectrum_transfer(
    output: np.ndarray, example: np.ndarray, reference: np.ndarray, bands: int, most: float, keep_power: bool = True
) -> np.ndarray:
    """``output`` (T, F) with each shaped channel's DCT coefficients (mean excluded) scaled per band by
    sqrt(example power / reference power), the gain clipped to [1 / ``most``, ``most``], then (``keep_power``) the
    channel's non-mean power restored to the output's own."""
    cols = shaped_channels()
    frames = output.shape[0]
    if frames < 2 * bands:  # too short for a band to hold a coefficient
        return output
    ex, ref = (torch.from_numpy(np.ascontiguousarray(m[:, cols], dtype=np.float64)) for m in (example, reference))
    gain = (band_power(ex - ex.mean(0), bands) / band_power(ref - ref.mean(0), bands).clamp(min=1e-12)).sqrt()
    gain = gain.clamp(1.0 / most, most)
    gain[0] = 1.0  # the lowest band holds the mean and the clip's drift: the content's
    dct = dct_matrix(frames, torch.float64)
    x = torch.from_numpy(np.ascontiguousarray(output[:, cols], dtype=np.float64))
    coeffs = dct @ x
    scaled = coeffs * gain[band_of_coefficients(frames, bands)]
    before = coeffs[1:].square().sum(0)
    after = scaled[1:].square().sum(0).clamp(min=1e-24)
    if keep_power:
        scaled[1:] *= (before / after).sqrt()
    scaled[0] = coeffs[0]
    out = output.copy()
    out[:, cols] = (dct.T @ scaled).numpy().astype(np.float32)
    return out


@output_shapers.register("spectrum")
class Spectrum(OutputShaper):
    """The examples' power per band over their references', at the output's own total power (module doc)."""

    needs_reference = True

    def __init__(self, bands: int = 16, most: float = 4.0, keep_power: bool = True) -> None:
        if bands < 2 or most < 1.0:
            raise ValueError(f"spectrum needs bands >= 2 and most >= 1, got {bands}, {most}")
        self.bands, self.most, self.keep_power = bands, most, keep_power

    def __call__(self, output: np.ndarray, context: ShapeContext) -> np.ndarray:
        if context.reference is None:
            raise ValueError("the spectrum shaper needs the example's reference")
        return spectrum_transfer(output, context.example, context.reference, self.bands, self.most, self.keep_power)
