"""The lab's spectral style shaper (``lab/style_spectrum.py``) on arrays: what it keeps and what it moves."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lab.style_spectrum import Spectrum, shaped_channels, spectrum_transfer
from motionaug.augment.methods.hooks import ShapeContext, output_shapers
from motionaug.augment.motion.spectrum import band_power


def wave(frames: int, hz: float, rng: np.random.Generator, fps: float = 20.0) -> np.ndarray:
    """(frames, 263) channels of one sine at ``hz`` with random phases and amplitudes, plus a little noise."""
    t = np.arange(frames)[:, None] / fps
    phase, amp = rng.uniform(0, 2 * np.pi, (1, 263)), rng.uniform(0.5, 2.0, (1, 263))
    return (amp * np.sin(2 * np.pi * hz * t + phase) + 0.05 * rng.standard_normal((frames, 263))).astype(np.float32)


def test_it_registers_and_needs_a_reference() -> None:
    shaper = output_shapers.create({"name": "spectrum", "bands": 8})
    assert isinstance(shaper, Spectrum) and Spectrum.needs_reference
    x = np.zeros((40, 263), np.float32)
    with pytest.raises(ValueError, match="reference"):
        shaper(x, ShapeContext(content=x, example=x, reference=None, fps=20.0))
    with pytest.raises(ValueError, match="bands"):
        Spectrum(bands=1)


def test_the_same_example_and_reference_change_nothing() -> None:
    rng = np.random.default_rng(0)
    content, example = wave(120, 1.0, rng), wave(90, 3.0, rng)
    out = spectrum_transfer(content, example, example, bands=16, most=4.0)
    np.testing.assert_allclose(out, content, atol=1e-5)


def test_power_moves_toward_the_examples_band_and_the_rest_is_kept() -> None:
    rng = np.random.default_rng(1)
    content = wave(160, 1.0, rng) + 0.5 * wave(160, 4.0, rng)
    reference, example = wave(160, 1.0, rng), wave(160, 4.0, rng)  # the style: fast motion, where plain is slow
    out = spectrum_transfer(content, example, reference, bands=16, most=4.0)
    cols = shaped_channels()
    others = np.setdiff1d(np.arange(263), cols)
    np.testing.assert_array_equal(out[:, others], content[:, others])  # root path and foot contacts untouched
    np.testing.assert_allclose(out[:, cols].mean(0), content[:, cols].mean(0), atol=1e-4)
    np.testing.assert_allclose(out[:, cols].var(0), content[:, cols].var(0), rtol=1e-3)  # amplitude kept

    def fast_share(x: np.ndarray) -> float:
        power = band_power(torch.from_numpy(x[:, cols] - x[:, cols].mean(0)).double(), 16)
        return float((power[5:].sum(0) / power.sum(0)).mean())

    assert fast_share(out) > fast_share(content) + 0.2
