"""Tempo (augment.motion.tempo): a motion's cycle, a style's tempo from its examples, retiming clips and captions.

Synthetic clips rendered with a known clock give the ground truth: the animator's phase rate is the content's
cycle rate times the style's ``tempo``, so the measured ratio must come back as that number.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from motionaug.augment.motion.features import extract_features, feature_slices, features_to_joints
from motionaug.augment.motion.tempo import (
    cycle_period,
    ground_speed,
    paced,
    retime,
    retime_captions,
    retimed_length,
    style_tempo,
)
from motionaug.augment.synth import render, sample_spec
from motionaug.augment.synth.styles import NEUTRAL, STYLES
from motionaug.schemas.captions import Caption
from motionaug.schemas.skeleton import T2M

FPS = 20.0


def features(content: str, seed: int, style: str = "neutral", tempo: float | None = None) -> np.ndarray:
    spec = sample_spec(np.random.default_rng(seed), content, style, seed=seed)
    params = dataclasses.replace(NEUTRAL, tempo=tempo) if tempo is not None else None
    return extract_features(render(spec, params).joints)


@pytest.mark.parametrize("content", ["walk", "run", "jump", "punch"])
def test_cycle_period_follows_the_clock(content: str) -> None:
    """The same clip rendered at 0.62x its phase rate repeats 1/0.62 times slower."""
    normal, slow = cycle_period(features(content, 1), FPS), cycle_period(features(content, 1, tempo=0.62), FPS)
    assert normal is not None and slow is not None
    assert normal / slow == pytest.approx(0.62, abs=0.02)


def test_motion_that_does_not_repeat_has_no_period() -> None:
    still = np.repeat(features("walk", 1)[:1], 80, axis=0)
    assert cycle_period(still, FPS) is None
    assert cycle_period(features("walk", 1)[:12], FPS) is None  # too short to hold a cycle
    tempo, why = style_tempo([(still, FPS)], [(features("walk", s), FPS) for s in range(3)])
    assert tempo is None and "do not repeat" in why


@pytest.mark.parametrize("style", ["proud", "depressed", "childlike"])
def test_style_tempo_from_one_example_against_neutral_references(style: str) -> None:
    """One styled walk against neutral walks of other specs: within 10% of the tempo the style was rendered at."""
    references = [(features("walk", seed), FPS) for seed in range(20, 32)]
    tempo, why = style_tempo([(features("walk", 10, style), FPS)], references)
    assert tempo == pytest.approx(STYLES[style].tempo, rel=0.1)
    assert "12 of 12 references" in why


def test_style_tempo_needs_enough_repeating_references() -> None:
    still = np.repeat(features("walk", 1)[:1], 80, axis=0)
    tempo, why = style_tempo([(features("walk", 10, "proud"), FPS)], [(still, FPS)] * 5)
    assert tempo is None and "0 of 5 neutral references repeat" in why


def _joints(f: np.ndarray) -> np.ndarray:
    return features_to_joints(torch.as_tensor(f), T2M).numpy()


@pytest.mark.parametrize("content", ["walk", "walk_curve", "turn"])
def test_retime_plays_the_clip_at_the_new_pace_on_the_same_path(content: str) -> None:
    f = features(content, 3)
    slow = retime(f, 0.5, max_frames=1000)
    assert slow.shape == (2 * len(f), f.shape[1]) and slow.dtype == np.float32
    j, js = _joints(f), _joints(slow)
    ric = feature_slices(T2M)["ric"]
    np.testing.assert_allclose(slow[::2][:, ric], f[:, ric], atol=1e-6)  # poses land on every other frame
    # the recovered path passes the same places at matching times (to 0.1 mm), curves and turns included
    np.testing.assert_allclose(js[::2, 0], j[:, 0], atol=1e-4)
    assert set(np.unique(slow[:, feature_slices(T2M)["feet"]])) <= {0.0, 1.0}  # contacts stay binary
    fast = retime(f, 2.0, max_frames=1000)
    assert len(fast) == retimed_length(len(f), 2.0, 1000) == round(len(f) / 2)
    np.testing.assert_allclose(_joints(fast)[:, 0], j[::2][: len(fast), 0], atol=1e-4)


def test_retime_caps_the_length_and_rejects_bad_tempo() -> None:
    f = features("walk", 1)
    assert len(retime(f, 0.5, max_frames=150)) == 150  # a slowed clip loses its end, never exceeds the cap
    same = retime(f, 1.0, max_frames=10)
    np.testing.assert_array_equal(same, f)
    assert same is not f
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="tempo must be > 0"):
            retime(f, bad, max_frames=100)


def test_retime_captions_moves_segments_with_the_clock() -> None:
    whole = Caption(text="a person walks proudly", tokens=["a/DET"])
    segment = Caption(text="a person waves", start=1.0, end=2.0)
    late = Caption(text="a person sits", start=4.0, end=5.0)
    out = retime_captions([whole, segment, late], 0.5, duration_s=6.0)
    assert out[0] == whole
    assert (out[1].start, out[1].end) == (2.0, 4.0)
    assert len(out) == 2  # the late segment starts after the retimed clip's end: nothing left of it
    assert out[1].text == segment.text and out[1].tokens == segment.tokens
    assert retime_captions([segment], 1.0, 1.0) == [segment]
    fast = retime_captions([segment], 2.0, duration_s=10.0)
    assert (fast[0].start, fast[0].end) == (0.5, 1.0)


@pytest.mark.parametrize("ratio", [0.3, 1.7])
def test_paced_carries_the_root_further_on_the_same_path_and_the_joints_with_it(ratio: float) -> None:
    f = features("walk", 5)
    joints = render(sample_spec(np.random.default_rng(5), "walk", "neutral", seed=5), None).joints
    root = joints[:, :1].copy()
    root[..., 1] = 0.0  # the ground track; a faster walk covers more of it, the body's poses and clock unchanged
    start = root[:1]
    faster = extract_features(joints + (ratio - 1.0) * (root - start))
    out = paced(f, ratio)
    assert out.dtype == np.float32 and out.shape == f.shape
    assert ground_speed(out) == pytest.approx(ratio * ground_speed(f), rel=1e-5)
    # the same features as extracting the walk whose root really went that far, joint velocities included; the
    # foot contacts stay the content's (measured from foot speed, a carried pose would slide off them)
    rest = [c for c in range(f.shape[1]) if c not in range(*feature_slices(T2M)["feet"].indices(f.shape[1]))]
    np.testing.assert_allclose(out[:, rest], faster[:, rest], atol=2e-4)
    np.testing.assert_array_equal(out[:, feature_slices(T2M)["feet"]], f[:, feature_slices(T2M)["feet"]])
    np.testing.assert_array_equal(paced(f, 1.0), f)
    with pytest.raises(ValueError, match="ratio must be > 0"):
        paced(f, 0.0)
