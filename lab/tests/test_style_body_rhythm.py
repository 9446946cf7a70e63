"""The lab's gain-form moment rule (``lab/style_moments_ratio.py``) and body-rhythm shaper
(``lab/style_body_rhythm.py``; the functions it shares with the product's ``in_place_rhythm`` are tested in
``tests/test_shapers.py``) on arrays: what each keeps and what it moves."""

from __future__ import annotations

import numpy as np
import pytest

import lab.style_body_rhythm  # noqa: F401  (registers body_rhythm)
import lab.style_moments_ratio  # noqa: F401  (registers moments_ratio)
from motionaug.augment.methods.hooks import ShapeContext, output_shapers
from motionaug.augment.methods.shapers import BELOW_HIPS
from motionaug.augment.methods.shapers import body_rhythm as rhythm
from motionaug.augment.motion.features import feature_slices
from motionaug.schemas.skeleton import T2M

FPS = 20.0
SLICES = feature_slices(T2M)


def clip(speed: float, seed: int, bounce: float = 0.0, frames: int = 60) -> np.ndarray:
    """Features (frames, 263): the root moving forwards at ``speed`` m/s, its height 0.95 m plus a ``bounce`` m sine
    two steps a second (every joint's height with it), the rest noise."""
    rng = np.random.default_rng(seed)
    m = rng.normal(0, 0.05, (frames, 263)).astype(np.float32)
    m[:, 1:3] = [0.0, speed / FPS]
    height = 0.95 + bounce * np.sin(2 * np.pi * 2.0 * np.arange(frames) / FPS)
    m[:, 3] = height
    ric = m[:, SLICES["ric"]].reshape(frames, -1, 3)
    ric[:, :, 1] += height[:, None].astype(np.float32)
    m[:, SLICES["ric"]] = ric.reshape(frames, -1)
    return m


def test_the_same_example_and_reference_keep_the_contents_spread() -> None:
    content, example = clip(0.02, 0), clip(1.2, 1)
    shaper = output_shapers.create("moments_ratio")
    out = shaper(content, ShapeContext(content=content, example=example, reference=example, fps=FPS))
    cols = np.r_[SLICES["root_y"], SLICES["ric"], SLICES["rot"], SLICES["local_vel"]]
    np.testing.assert_allclose(out[:, cols].std(0), content[:, cols].std(0), rtol=1e-4)


def test_the_gain_scales_the_spread_where_the_added_variance_barely_moves_it() -> None:
    content, reference = clip(0.02, 0), clip(1.2, 1)
    example = reference.copy()
    example[:, SLICES["rot"]] *= 0.5  # a style that halves one block's swing
    ctx = ShapeContext(content=3.0 * content, example=example, reference=reference, fps=FPS)
    ratio = output_shapers.create("moments_ratio")(3.0 * content, ctx)
    added = output_shapers.create("moments")(3.0 * content, ctx)
    rot = SLICES["rot"]
    np.testing.assert_allclose(ratio[:, rot].std(0), 3.0 * content[:, rot].std(0) * 0.5, rtol=1e-3)
    assert added[:, rot].std(0).mean() > 0.9 * 3.0 * content[:, rot].std(0).mean()


def test_a_travelling_examples_bounce_lowers_an_in_place_clip_above_the_knees() -> None:
    content, example, reference = clip(0.02, 0), clip(1.2, 1, bounce=0.04), clip(1.2, 2)
    out = output_shapers.create("body_rhythm")(content, ShapeContext(content, example, reference, FPS))
    drop, _ = rhythm(example, len(content))
    assert drop.max() == pytest.approx(0.0, abs=1e-6) and drop.min() < -0.07
    np.testing.assert_allclose(out[:, SLICES["root_y"]][:, 0] - content[:, 3], drop, atol=1e-5)
    moved = (out - content)[:, SLICES["ric"]].reshape(len(content), -1, 3)
    for joint in BELOW_HIPS:
        np.testing.assert_array_equal(moved[:, joint - 1], 0.0)
    np.testing.assert_allclose(moved[:, 0, 1], drop, atol=1e-5)  # the left hip goes down with the pelvis


def test_a_travelling_clip_or_an_in_place_example_is_left_alone() -> None:
    walk, wave = clip(1.2, 0), clip(0.02, 1)
    shaper = output_shapers.create("body_rhythm")
    np.testing.assert_array_equal(shaper(walk, ShapeContext(walk, clip(1.2, 2, 0.04), walk, FPS)), walk)
    np.testing.assert_array_equal(shaper(wave, ShapeContext(wave, clip(0.02, 3, 0.04), wave, FPS)), wave)
    with pytest.raises(ValueError, match="source"):
        output_shapers.create({"name": "body_rhythm", "source": "nobody"})


def test_an_in_place_examples_rhythm_reaches_an_in_place_clip_only_with_that_kind() -> None:
    wave, example = clip(0.02, 0), clip(0.02, 1, bounce=0.04)
    context = ShapeContext(wave, example, clip(0.02, 2), FPS)
    np.testing.assert_array_equal(output_shapers.create("body_rhythm")(wave, context), wave)
    out = output_shapers.create({"name": "body_rhythm", "example_kind": "in_place"})(wave, context)
    drop, _ = rhythm(example, len(wave))
    np.testing.assert_allclose(out[:, SLICES["root_y"]][:, 0] - wave[:, 3], drop, atol=1e-5)
    walk_example = ShapeContext(wave, clip(1.2, 3, bounce=0.04), wave, FPS)
    kind = output_shapers.create({"name": "body_rhythm", "example_kind": "in_place"})
    np.testing.assert_array_equal(kind(wave, walk_example), wave)
    with pytest.raises(ValueError, match="example_kind"):
        output_shapers.create({"name": "body_rhythm", "example_kind": "sideways"})


def test_excess_adds_only_the_body_motion_the_reference_lacks() -> None:
    wave, bouncing = clip(0.02, 0), clip(0.02, 1, bounce=0.04)
    excess = output_shapers.create({"name": "body_rhythm", "example_kind": "in_place", "excess": True})
    np.testing.assert_array_equal(excess(wave, ShapeContext(wave, bouncing, bouncing, FPS)), wave)
    plain = clip(0.02, 2, bounce=0.02)  # bobs at half the example's amplitude: a quarter of its variance
    out = excess(wave, ShapeContext(wave, bouncing, plain, FPS))
    full = output_shapers.create({"name": "body_rhythm", "example_kind": "in_place"})
    raised = full(wave, ShapeContext(wave, bouncing, plain, FPS))
    gained, whole = (np.abs(o[:, 3] - wave[:, 3]).max() for o in (out, raised))
    assert gained == pytest.approx(np.sqrt(0.75) * whole, rel=1e-3)
