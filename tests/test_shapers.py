"""The tempo, coordination (also over time lags and in bone coordinates), bone-length, foot-lock, foot-planting and
in-place rhythm shapers (``augment/methods/shapers.py``) on real-shaped features: what each keeps and moves."""

from __future__ import annotations

import numpy as np
import pytest

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.methods.hooks import ShapeContext, output_shapers
from motionaug.augment.methods.shapers import (
    BELOW_HIPS,
    STYLE_ERD_CHAIN,
    beyond_reference,
    body_rhythm,
    bone_channels,
    coordination_transfer,
    delays,
    flight,
    position_channels,
    toe_contacts,
    toe_heights,
    with_bone_channels,
    with_bone_lengths,
)
from motionaug.augment.methods.shaping import ShapedModel
from motionaug.augment.motion.features import feature_slices, features_to_joints
from motionaug.augment.motion.foot_lock import plant_feet
from motionaug.augment.motion.tempo import cycle_period, retime
from motionaug.augment.outputs.shards import TransferOutput
from motionaug.augment.synth.animator import sample_spec
from motionaug.augment.synth.corpus import spec_to_clip
from motionaug.schemas.captions import Caption
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


def bouncing(features: np.ndarray, bounce: float) -> np.ndarray:
    """``features`` with the root and every joint raised by a ``bounce`` m sine, two bobs a second."""
    out = features.copy()
    height = (bounce * np.sin(2 * np.pi * 2.0 * np.arange(len(out)) / 20.0)).astype(np.float32)
    ric = feature_slices(T2M)["ric"]
    out[:, 3] += height
    out[:, ric] = (
        out[:, ric].reshape(len(out), -1, 3) + np.stack([0 * height, height, 0 * height], -1)[:, None]
    ).reshape(len(out), -1)
    return out


def test_in_place_rhythm_adds_to_a_standing_clip_the_bounce_its_reference_lacks() -> None:
    content, plain = clip("neutral", "wave", seed=0), clip("neutral", "wave", seed=1)
    example = bouncing(plain, 0.04)
    shaper = output_shapers.create("in_place_rhythm")
    assert "in_place_rhythm" in STYLE_ERD_CHAIN
    same = shaper(content, ShapeContext(content, example, example, 20.0))
    np.testing.assert_allclose(same, content, atol=1e-5)  # channels still to 1e-6 m keep their micrometres
    out = shaper(content, ShapeContext(content, example, plain, 20.0))
    width = 20  # highpass_s 1.0 at 20 fps
    drop, _ = beyond_reference(*body_rhythm(example, len(content), width), body_rhythm(plain, len(content), width))
    assert drop.min() < -0.06  # the bob's 8 cm, high-passed
    np.testing.assert_allclose(out[:, 3] - content[:, 3], drop, atol=1e-5)
    moved = (out - content)[:, feature_slices(T2M)["ric"]].reshape(len(content), -1, 3)
    for joint in BELOW_HIPS:
        np.testing.assert_array_equal(moved[:, joint - 1], 0.0)  # the knees are plant_feet's
    np.testing.assert_allclose(moved[:, 0, 1], drop, atol=1e-5)  # the left hip goes down with the pelvis


def test_in_place_rhythm_leaves_a_travelling_clip_or_example_alone() -> None:
    walk, wave = clip("neutral", seed=0), clip("neutral", "wave", seed=1)
    shaper = output_shapers.create({"name": "in_place_rhythm", "highpass_s": 0.5})
    np.testing.assert_array_equal(shaper(walk, ShapeContext(walk, bouncing(wave, 0.04), wave, 20.0)), walk)
    np.testing.assert_array_equal(shaper(wave, ShapeContext(wave, bouncing(walk, 0.04), walk, 20.0)), wave)
    with pytest.raises(ValueError, match="highpass_s"):
        output_shapers.create({"name": "in_place_rhythm", "highpass_s": -1.0})
    with pytest.raises(ValueError, match="reference"):
        shaper(wave, ShapeContext(wave, wave, None, 20.0))


def test_the_high_pass_takes_a_takes_slow_drift_out_of_its_rhythm() -> None:
    example = bouncing(clip("neutral", "wave", seed=1), 0.04)[:80]
    drifting = example.copy()
    drifting[:, 3] += np.linspace(0.0, -0.2, len(example)).astype(np.float32)  # the take sinks 20 cm
    looped, _ = body_rhythm(drifting, 160)
    assert looped[79] - looped[80] < -0.15  # looped raw, the drift jumps back up where the take starts again
    steady, _ = body_rhythm(example, 160, 20)
    filtered, _ = body_rhythm(drifting, 160, 20)
    assert np.abs(np.diff(filtered)).max() < 1.5 * np.abs(np.diff(steady)).max()


def test_beyond_reference_keeps_the_share_of_the_variance_the_reference_lacks() -> None:
    wave = clip("neutral", "wave", seed=1)
    example, half = body_rhythm(bouncing(wave, 0.04), 100), body_rhythm(bouncing(wave, 0.02), 100)
    drop, sway = beyond_reference(*example, half)  # half the amplitude: a quarter of the variance
    ratio = drop.std() / example[0].std()
    assert ratio == pytest.approx(np.sqrt(1 - half[0].var() / example[0].var()), rel=1e-6) and 0.5 < ratio < 1.0
    assert np.abs(sway).max() <= np.abs(example[1]).max()
    np.testing.assert_array_equal(beyond_reference(*example, example)[0], 0.0)


class Unchanged:
    """A style model that gives each clip back as it came (the output the shapers then shape)."""

    style = "slow"

    def transfer(self, clips, seed: int = 0):
        return [TransferOutput(c.id, self.style, c.motion.copy(), list(c.captions)) for c in clips]


def test_match_tempo_plays_the_output_at_the_examples_rate_and_the_later_steps_on_that_clock() -> None:
    content, reference = clip("neutral", seed=0), clip("neutral", seed=1)
    example = retime(reference, 0.5, 400)  # the reference's walk at half its cadence: a style's tempo alone
    context = ShapeContext(content, example, reference, 20.0)
    shaper = output_shapers.create("match_tempo")
    out, after = shaper(content, context), shaper.context_after(context)
    assert len(out) == min(2 * len(content), max(len(content), 196)) and out.shape[1] == content.shape[1]
    assert len(after.content) == len(out) and after.example is example
    assert cycle_period(after.reference, 20.0) == pytest.approx(cycle_period(example, 20.0), rel=0.1)
    assert cycle_period(out, 20.0) == pytest.approx(2 * cycle_period(content, 20.0), rel=0.1)
    moved = output_shapers.create("moments")(out, after)  # a later step reads clips of one length
    assert moved.shape == out.shape and np.isfinite(moved).all()
    same = ShapeContext(content, reference, reference, 20.0)
    np.testing.assert_array_equal(shaper(content, same), content)  # the same pace: nothing to retime
    assert shaper.context_after(same) is same


def test_match_tempo_keeps_the_clock_across_kinds_of_motion_and_gaits() -> None:
    walk, wave, reference = clip("neutral", seed=2), clip("neutral", "wave", seed=3), clip("neutral", seed=4)
    slow = retime(reference, 0.5, 400)
    shaper = output_shapers.create("match_tempo")
    np.testing.assert_array_equal(shaper(wave, ShapeContext(wave, slow, reference, 20.0)), wave)  # a wave, a walk
    running = reference.copy()
    running[::2, -4:] = 0.0  # no foot down on every other frame: a run's flight phases
    assert flight(running) > 0.4 and flight(slow) < 0.1
    np.testing.assert_array_equal(shaper(walk, ShapeContext(walk, slow, running, 20.0)), walk)
    with pytest.raises(ValueError, match="needs the example's reference"):
        shaper(walk, ShapeContext(walk, slow, None, 20.0))


def test_a_retimed_output_comes_back_with_its_caption_segments_retimed() -> None:
    content, reference = clip("neutral", seed=5), clip("neutral", seed=6)
    captions = [Caption(text="a person walks"), Caption(text="a person walks forward", start=1.0, end=2.0)]
    source = MotionClip("walk_0", content, captions, 20.0)
    model = ShapedModel(Unchanged(), [output_shapers.create("match_tempo")], [retime(reference, 0.5, 400)], [reference])
    (out,) = model.transfer([source])
    assert len(out.motion) > 1.5 * len(content)
    whole, segment = out.captions
    assert whole == captions[0]
    tempo = len(content) / len(out.motion)
    assert (segment.start, segment.end) == pytest.approx((1.0 / tempo, 2.0 / tempo), abs=1e-3)


def test_bone_coordinates_rebuild_the_joints_and_the_bone_map_moves_the_bones_coupling_toward_the_examples() -> None:
    content, example, reference = clip("neutral"), clip("old", seed=1), clip("neutral", seed=2)
    np.testing.assert_allclose(with_bone_channels(content, bone_channels(content)), content, atol=1e-6)
    np.testing.assert_allclose(
        coordination_transfer(content, example, example, 0.0, 1e-3, lag=3, taps=6, basis="bones"), content, atol=1e-4
    )
    out = coordination_transfer(reference, example, reference, 0.0, 1e-6, lag=3, taps=2, basis="bones")
    want = lagged_cross_covariance(bone_channels(example), 3)
    gap = [np.abs(lagged_cross_covariance(bone_channels(x), 3) - want).max() for x in (reference, out)]
    assert gap[1] < 0.5 * gap[0]
    in_positions = coordination_transfer(reference, example, reference, 0.0, 1e-6, lag=3, taps=2)
    assert np.abs(out - in_positions).max() > 1e-2  # the basis matters: the square roots are not invariant to it
    with pytest.raises(ValueError, match="basis"):
        output_shapers.create({"name": "coordination", "basis": "angles"})


def test_the_bone_basis_shaper_is_its_transfer_and_plays_an_opposed_clip_backwards() -> None:
    example, reference = clip("proud", seed=3), clip("neutral", seed=2)
    backward, forward = clip("neutral", "walk_backward", seed=4), clip("neutral", seed=5)
    shaper = output_shapers.create({"name": "coordination", "lag": 3, "taps": 2, "basis": "bones"})
    for content in (forward, backward):
        got = shaper(content, ShapeContext(content=content, example=example, reference=reference, fps=20.0))
        if content is backward:
            played_back = content[::-1].copy()
            want = coordination_transfer(played_back, example, reference, 0.0, 1e-3, lag=3, taps=2, basis="bones")
            want = want[::-1]
            as_recorded = coordination_transfer(content, example, reference, 0.0, 1e-3, lag=3, taps=2, basis="bones")
            assert np.abs(want - as_recorded).max() > 1e-2  # so the rule is what this test checks
        else:
            want = coordination_transfer(content, example, reference, 0.0, 1e-3, lag=3, taps=2, basis="bones")
        np.testing.assert_allclose(got, want, atol=1e-6)
