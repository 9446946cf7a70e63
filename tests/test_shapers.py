"""The coordination (also over time lags), bone-length, foot-lock and foot-planting shapers
(``augment/methods/shapers.py``) on real-shaped features: what each keeps and moves."""

from __future__ import annotations

import numpy as np
import pytest

from motionaug.augment.methods.hooks import ShapeContext, output_shapers
from motionaug.augment.methods.shapers import (
    coordination_transfer,
    delays,
    position_channels,
    toe_contacts,
    toe_heights,
    with_bone_lengths,
)
from motionaug.augment.motion.features import features_to_joints
from motionaug.augment.motion.foot_lock import plant_feet
from motionaug.augment.synth.animator import sample_spec
from motionaug.augment.synth.corpus import spec_to_clip
from motionaug.schemas.skeleton import T2M


def clip(style: str, content: str = "walk", seed: int = 0) -> np.ndarray:
    """A rendered synthetic clip's features (a real skeleton: constant bone lengths)."""
    return spec_to_clip(sample_spec(np.random.default_rng(seed), content, style, seed=seed), "c").motion


def bone_lengths(features: np.ndarray) -> np.ndarray:
    joints = features_to_joints(features)
    pairs = [(a, b) for chain in T2M.kinematic_chain for a, b in zip(chain[:-1], chain[1:])]
    return np.stack([np.linalg.norm(joints[:, b] - joints[:, a], axis=-1) for a, b in pairs], axis=-1)


def test_they_register_and_coordination_needs_a_reference() -> None:
    assert {"coordination", "bone_lengths", "lock_feet"} <= set(output_shapers.names())
    x = clip("neutral")
    with pytest.raises(ValueError, match="reference"):
        output_shapers.create("coordination")(x, ShapeContext(content=x, example=x, reference=None, fps=20.0))
    with pytest.raises(ValueError, match="shrink"):
        output_shapers.create({"name": "coordination", "shrink": 2.0})


def test_the_same_example_and_reference_change_nothing() -> None:
    content, example = clip("neutral"), clip("old", seed=1)
    np.testing.assert_allclose(coordination_transfer(content, example, example, 0.0, 1e-3), content, atol=1e-4)


def test_a_plain_content_comes_out_with_the_examples_covariance_and_the_rest_is_kept() -> None:
    reference, example = clip("neutral", seed=2), clip("old", seed=3)
    out = coordination_transfer(reference, example, reference, 0.0, 1e-6)
    cols = position_channels()
    got, want = np.cov(out[:, cols], rowvar=False), np.cov(example[:, cols], rowvar=False)
    before = np.abs(np.cov(reference[:, cols], rowvar=False) - want).max()
    assert np.abs(got - want).max() < 0.1 * before  # near-flat directions are floored, so not exact
    others = np.setdiff1d(np.arange(out.shape[1]), cols)
    np.testing.assert_array_equal(out[:, others], reference[:, others])
    np.testing.assert_allclose(out[:, cols].mean(0), reference[:, cols].mean(0), atol=1e-5)


def test_bone_lengths_are_the_contents_again() -> None:
    content, example, reference = clip("neutral"), clip("old", seed=1), clip("neutral", seed=4)
    stretched = coordination_transfer(content, example, reference, 0.0, 1e-3)
    assert np.abs(bone_lengths(stretched) - bone_lengths(content).mean(0)).max() > 0.01  # the map stretches bones
    fixed = with_bone_lengths(stretched, content)
    np.testing.assert_allclose(
        bone_lengths(fixed), bone_lengths(content).mean(0)[None].repeat(len(fixed), 0), atol=1e-4
    )
    np.testing.assert_allclose(with_bone_lengths(content, content), content, atol=1e-5)  # a skeleton stays as it is


def test_delays_stack_each_frame_with_the_frames_before_it() -> None:
    x = np.arange(10, dtype=np.float64)[:, None]
    stacked = delays(x, lag=2, taps=2)
    np.testing.assert_array_equal(stacked[6], [6, 4, 2])
    np.testing.assert_array_equal(stacked[1], [1, 0, 0])  # the first frame stands in before the clip starts
    assert delays(x, lag=3, taps=0) is x


def lagged_cross_covariance(x: np.ndarray, lag: int) -> np.ndarray:
    d = x - x.mean(0)
    return d[lag:].T @ d[:-lag] / (len(x) - lag)


def test_the_lagged_map_keeps_a_content_with_its_example_and_moves_the_lagged_coupling_toward_the_examples() -> None:
    content, example, reference = clip("neutral"), clip("old", seed=1), clip("neutral", seed=2)
    same = coordination_transfer(content, example, example, 0.0, 1e-3, lag=3, taps=6)
    np.testing.assert_allclose(same, content, atol=1e-4)
    cols = position_channels()
    out = coordination_transfer(reference, example, reference, 0.0, 1e-6, lag=3, taps=2)
    want = lagged_cross_covariance(example[:, cols], 3)
    for x in (reference, out):
        assert np.isfinite(x).all()
    gap = [np.abs(lagged_cross_covariance(x[:, cols], 3) - want).max() for x in (reference, out)]
    assert gap[1] < 0.5 * gap[0]
    with pytest.raises(ValueError, match="taps"):
        output_shapers.create({"name": "coordination", "taps": -1})


def test_plant_feet_registers_and_reads_the_contents_contacts() -> None:
    content = clip("neutral")
    example = clip("old", seed=1)
    shaped = coordination_transfer(content, example, content, 0.0, 1e-3)
    planted = output_shapers.create("plant_feet")(
        shaped, ShapeContext(content=content, example=example, reference=content, fps=20.0)
    )
    np.testing.assert_array_equal(planted, plant_feet(shaped, toe_contacts(content), clearance=toe_heights(content)))
    with pytest.raises(ValueError, match="clearance"):
        output_shapers.create({"name": "plant_feet", "clearance": 2.0})


def test_the_coordination_shaper_keeps_one_map_per_example_and_reference() -> None:
    content, reference = clip("neutral"), clip("neutral", seed=2)
    shaper = output_shapers.create({"name": "coordination", "lag": 3, "taps": 2})
    for example in (clip("old", seed=1), clip("proud", seed=3), clip("old", seed=1)):
        got = shaper(content, ShapeContext(content=content, example=example, reference=reference, fps=20.0))
        want = coordination_transfer(content, example, reference, 0.0, 1e-3, lag=3, taps=2)
        np.testing.assert_array_equal(got, want)  # a cached map is the map of this example, not the last one


def test_a_clip_travelling_against_the_example_is_mapped_played_backwards() -> None:
    example, reference = clip("proud", seed=3), clip("neutral", seed=2)  # forward walks
    backward, forward = clip("neutral", "walk_backward", seed=4), clip("neutral", seed=5)
    lagged = output_shapers.create({"name": "coordination", "lag": 3, "taps": 2})

    def shaped(shaper, content: np.ndarray) -> np.ndarray:
        return shaper(content, ShapeContext(content=content, example=example, reference=reference, fps=20.0))

    played_back = coordination_transfer(backward[::-1].copy(), example, reference, 0.0, 1e-3, lag=3, taps=2)[::-1]
    as_recorded = coordination_transfer(backward, example, reference, 0.0, 1e-3, lag=3, taps=2)
    np.testing.assert_allclose(shaped(lagged, backward), played_back, atol=1e-6)
    assert np.abs(played_back - as_recorded).max() > 1e-2  # the lag's direction matters to this clip
    want = coordination_transfer(forward, example, reference, 0.0, 1e-3, lag=3, taps=2)
    np.testing.assert_array_equal(shaped(lagged, forward), want)  # a clip going the example's way: as before
    zero_lag = output_shapers.create("coordination")  # no lag, no direction in time: one map either way
    np.testing.assert_allclose(
        shaped(zero_lag, backward), coordination_transfer(backward, example, reference, 0.0, 1e-3), atol=1e-6
    )
