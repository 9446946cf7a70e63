"""The lab's part-wise coordination shaper (``lab/style_coordination_parts.py``): which channels each part maps."""

from __future__ import annotations

import numpy as np
import pytest

from lab.style_coordination_parts import part_channels
from motionaug.augment.methods.hooks import ShapeContext, output_shapers
from motionaug.augment.methods.shapers import position_channels
from motionaug.augment.synth.animator import sample_spec
from motionaug.augment.synth.corpus import spec_to_clip


def clip(style: str, seed: int) -> np.ndarray:
    return spec_to_clip(sample_spec(np.random.default_rng(seed), "walk", style, seed=seed), "c").motion


def test_the_parts_split_the_position_channels() -> None:
    upper, lower = part_channels("upper"), part_channels("lower")
    assert not set(upper) & set(lower)
    assert sorted(np.r_[upper, lower]) == sorted(position_channels())
    with pytest.raises(ValueError, match="upper or lower"):
        part_channels("arms")


def test_only_the_chosen_part_moves() -> None:
    content, example, reference = clip("neutral", 0), clip("old", 1), clip("neutral", 2)
    context = ShapeContext(content=content, example=example, reference=reference, fps=20.0)
    out = output_shapers.create({"name": "coordination_parts", "parts": "upper"})(content, context)
    kept = np.setdiff1d(np.arange(content.shape[1]), part_channels("upper"))
    np.testing.assert_array_equal(out[:, kept], content[:, kept])
    assert np.abs(out[:, part_channels("upper")] - content[:, part_channels("upper")]).max() > 1e-3
