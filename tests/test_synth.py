"""The procedural style corpus: animator physics, paired rendering, captions, corpus files, learnability."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import FIXTURES
from pydantic import ValidationError

from motionaug.augment.synth import CONTENTS, STYLE_WORDS, STYLES, ClipSpec, render, sample_spec
from motionaug.augment.synth.animator import BONE_LENGTHS, FOOT_JOINTS, PARENTS
from motionaug.augment.synth.captions import LEXICON, make_captions
from motionaug.augment.synth.contents import L_FOOT, R_FOOT
from motionaug.augment.synth.corpus import (
    assign_splits,
    generate_corpus,
    linear_probe_predict,
    plan_specs,
    pooled_descriptor,
    read_labels,
    spec_to_clip,
)
from motionaug.augment.synth.styles import style_params
from motionaug.augment.text.tokens import UPOS_TAGS
from motionaug.schemas.errors import MotionDataError


@pytest.fixture
def one_thread():
    """Feature extraction on one torch thread: other test files share the two cores."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def bone_lengths(joints: np.ndarray) -> np.ndarray:
    """(T, 21) parent->joint distances."""
    return np.stack([np.linalg.norm(joints[:, j] - joints[:, PARENTS[j]], axis=-1) for j in range(1, 22)], axis=1)


def spec(content: str, style: str = "neutral", **kw) -> ClipSpec:
    return ClipSpec(content=content, style=style, seed=11, duration=kw.pop("duration", 4.0), **kw)


# --- animator ---------------------------------------------------------------------------------


@pytest.mark.parametrize("content", sorted(CONTENTS))
def test_every_content_renders_in_every_style(content: str) -> None:
    rng = np.random.default_rng(0)
    for style in STYLES:
        s = sample_spec(rng, content, style)
        clip = render(s)
        assert clip.joints.shape == (s.n_frames, 22, 3) and clip.joints.dtype == np.float32
        assert np.isfinite(clip.joints).all()
        assert 2.0 <= s.duration <= 8.0
        lengths = bone_lengths(clip.joints.astype(np.float64))
        assert np.ptp(lengths, axis=0).max() < 1e-4, "bones must keep their length within a clip"
        assert np.allclose(lengths[0], BONE_LENGTHS[1:] * np.array(s.bone_scale[1:]), atol=1e-4)
        feet = clip.joints[:, FOOT_JOINTS, 1].min(axis=1)
        assert clip.joints[..., 1].min() > -1e-4, "nothing goes through the floor"
        assert np.abs(feet[clip.ground]).max() < 1e-4, "a foot touches the floor on every ground frame"
        assert clip.joints[:, 15, 1].mean() > 1.1, "head stays well above the floor"


def test_bone_lengths_come_from_the_reference_skeleton() -> None:
    ref = np.load(FIXTURES / "humanml3d" / "joints" / "000021.npy")[0, :22]
    lengths = np.array([np.linalg.norm(ref[j] - ref[PARENTS[j]]) for j in range(1, 22)])
    pairs = [(1, 2), (4, 5), (7, 8), (10, 11), (13, 14), (16, 17), (18, 19), (20, 21)]
    for a, b in pairs:
        lengths[a - 1] = lengths[b - 1] = 0.5 * (lengths[a - 1] + lengths[b - 1])
    assert np.allclose(BONE_LENGTHS[1:], lengths, atol=1e-3)


def test_jump_leaves_the_floor_and_walking_feet_do_not_skate() -> None:
    jump = render(spec("jump", travel=0.5))
    assert (~jump.ground).any() and jump.joints[~jump.ground][:, FOOT_JOINTS, 1].min(axis=1).max() > 0.1
    walk = render(spec("walk", duration=6.0)).joints
    toes = walk[:, [L_FOOT, R_FOOT]]
    stance = np.argmin(toes[:-1, :, 1], axis=1)
    t = np.arange(len(toes) - 1)
    slide = np.linalg.norm(toes[1:, :, [0, 2]][t, stance] - toes[:-1, :, [0, 2]][t, stance], axis=1) * 20.0
    assert np.median(slide) < 0.02 and np.mean(slide) < 0.15, "the planted foot must not slide"
    speed = np.linalg.norm(walk[-1, 0, [0, 2]] - walk[0, 0, [0, 2]]) / 6.0
    assert 0.8 < speed < 1.8, f"walking speed {speed:.2f} m/s is not a walk"
    kick = render(spec("kick")).joints
    assert np.linalg.norm(kick[-1, 0, [0, 2]] - kick[0, 0, [0, 2]]) < 0.2, "a kick stays on the spot"


def test_walk_backward_and_sidestep_move_the_right_way() -> None:
    back = render(spec("walk_backward", heading=0.0))
    assert back.joints[-1, 0, 2] - back.joints[0, 0, 2] < -1.0
    left = render(spec("sidestep", heading=0.0, side="left")).joints
    right = render(spec("sidestep", heading=0.0, side="right")).joints
    assert left[-1, 0, 0] - left[0, 0, 0] > 0.5 and right[-1, 0, 0] - right[0, 0, 0] < -0.5


def test_paired_rendering_keeps_content_duration_bones_and_path_shape() -> None:
    base = spec("walk_curve", heading=0.7, curvature=0.5, side="right", bone_scale=(1.0,) + (1.03,) * 21, duration=6)
    neutral = render(base)
    for style in ("proud", "old", "angry"):
        styled = render(base.with_style(style))
        assert styled.spec.content == base.content and styled.spec.duration == base.duration
        assert styled.joints.shape == neutral.joints.shape
        assert np.allclose(bone_lengths(styled.joints)[0], bone_lengths(neutral.joints)[0], atol=1e-4)
        assert not np.allclose(styled.joints, neutral.joints, atol=1e-2)
        for clip in (neutral, styled):
            path = clip.joints[:, 0, [0, 2]]
            dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
            slope = np.polyfit(dist, clip.heading, 1)[0]
            assert slope == pytest.approx(-0.5, abs=0.06), "the path turns by the same angle per metre"
            assert clip.heading[0] == pytest.approx(0.7)
    assert base.with_style("old").with_style("neutral") == base


def test_styles_change_posture_the_way_people_read_them() -> None:
    def lean(joints: np.ndarray) -> float:
        """Mean forward (+Z, the facing of these clips) offset of the neck from the pelvis."""
        return float(np.mean(joints[:, 12, 2] - joints[:, 0, 2]))

    clips = {s: render(spec("walk", s, heading=0.0, duration=5.0)) for s in STYLES}
    j = {s: c.joints for s, c in clips.items()}
    assert lean(j["old"]) > lean(j["neutral"]) + 0.05 and lean(j["proud"]) < lean(j["neutral"])
    head_drop = {s: float(np.mean(j[s][:, 12, 1] - j[s][:, 15, 1])) for s in STYLES}
    assert head_drop["depressed"] > head_drop["neutral"] + 0.03 > head_drop["proud"] + 0.03
    speed = {s: np.linalg.norm(j[s][-1, 0, [0, 2]] - j[s][0, 0, [0, 2]]) / 5.0 for s in STYLES}
    assert speed["childlike"] > speed["neutral"] > speed["depressed"] and speed["old"] < 0.7 * speed["neutral"]
    pelvis = {s: float(np.mean(j[s][:, 0, 1])) for s in STYLES}
    assert pelvis["old"] < pelvis["neutral"] - 0.02 and pelvis["sneaky"] < pelvis["old"], "bent knees lower the hips"


def test_spec_json_round_trip_and_bad_input() -> None:
    s = sample_spec(np.random.default_rng(5), "wave", "proud")
    again = ClipSpec.from_json(s.to_json())
    assert again == s and np.array_equal(render(again).joints, render(s).joints)
    with pytest.raises(MotionDataError, match="clip spec"):
        ClipSpec.from_json('{"content": "moonwalk"}')
    with pytest.raises(ValidationError):
        ClipSpec(content="walk", style="sleepy")
    with pytest.raises(MotionDataError, match="unknown style"):
        style_params("sleepy")


# --- captions ---------------------------------------------------------------------------------


def test_captions_have_valid_tokens_and_name_the_style() -> None:
    rng = np.random.default_rng(2)
    style_words = {
        s: {w.adjective, *(w.adverb or "").split(), *(t for p in w.phrases for t in p.split())}
        for s, w in STYLE_WORDS.items()
    }
    all_style_words = {
        "proud",
        "proudly",
        "depressed",
        "sadly",
        "old",
        "elderly",
        "childlike",
        "playfully",
        "angry",
        "angrily",
        "strutting",
        "strut",
        "swagger",
        "sneaky",
        "sneakily",
    }
    for i in range(240):
        content, style = sorted(CONTENTS)[i % len(CONTENTS)], sorted(STYLES)[i % len(STYLES)]
        s = sample_spec(rng, content, style)
        captions = make_captions(s)
        assert len(captions) == 3 and len({c.text for c in captions}) == 3
        assert make_captions(s) == captions, "captions are deterministic"
        for c in captions:
            words = c.text.split()
            assert c.whole_clip and c.text == c.text.lower() and len(c.tokens) == len(words)
            for word, token in zip(words, c.tokens):
                lemma, pos = token.split("/")
                assert pos in UPOS_TAGS and lemma == lemma.lower()
                if pos == "VERB":
                    assert lemma == LEXICON.get(word, (lemma,))[0] and not lemma.endswith(("ing", "ks", "ps"))
            if style == "neutral":
                assert not set(words) & all_style_words, c.text
            else:
                assert set(words) & (style_words[style] - {"a", "an", "in", "way", "like", "with", "the", "person"})
    walk = make_captions(ClipSpec(content="walk", style="proud", seed=3))
    assert any("walk/VERB" in c.tokens for c in walk) or any("stroll/VERB" in c.tokens for c in walk)


# --- corpus -----------------------------------------------------------------------------------


def _digest(root: Path) -> dict[str, str]:
    files = sorted(p for p in root.rglob("*") if p.is_file())
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() for p in files}


def test_generate_corpus_layout_is_deterministic_and_re_renderable(tmp_path: Path, one_thread: None) -> None:
    a = generate_corpus(tmp_path / "a", 20, seed=4)
    generate_corpus(tmp_path / "b", 20, seed=4)
    generate_corpus(tmp_path / "c", 20, seed=5)
    files_a = _digest(tmp_path / "a")
    assert files_a == _digest(tmp_path / "b"), "same seed must give byte-identical output"
    assert files_a != _digest(tmp_path / "c")
    root = tmp_path / "a"
    assert len(list((root / "new_joint_vecs").glob("*.npy"))) == 20 and len(list((root / "texts").glob("*.txt"))) == 20
    assert np.load(root / "Mean.npy").shape == (263,) and (np.load(root / "Std.npy") > 0).all()
    splits = {name: (root / f"{name}.txt").read_text().split() for name in ("train", "val", "test", "all")}
    assert sorted(splits["train"] + splits["val"] + splits["test"]) == sorted(splits["all"])
    assert len(splits["train"]) == 16 and a.splits == {"train": 16, "val": 2, "test": 2}
    labels = read_labels(root)
    assert [r["id"] for r in labels] == splits["all"]
    first = labels[0]
    respec = ClipSpec.model_validate(first["spec"])
    stored = np.load(root / "new_joint_vecs" / f"{first['id']}.npy")
    assert np.array_equal(spec_to_clip(respec, first["id"]).motion, stored), "labels re-render the stored clip"
    with pytest.raises(MotionDataError, match="not empty"):
        generate_corpus(root, 5, seed=4)
    line = (root / "texts" / f"{first['id']}.txt").read_text().splitlines()[0]
    text, tokens, start, end = line.split("#")
    assert tokens.split() and start == "0.0" and end == "0.0"


def test_plan_mix_and_splits() -> None:
    specs = plan_specs(100, seed=1, neutral_fraction=0.4)
    styles = [s.style for s in specs]
    assert styles.count("neutral") == 40 and set(styles) == set(STYLES)
    assert {s.content for s in specs} == set(CONTENTS)
    only = plan_specs(10, seed=1, styles=["angry"], contents=["kick"])
    assert {(s.content, s.style) for s in only} == {("kick", "angry")}
    with pytest.raises(MotionDataError, match="styles"):
        plan_specs(10, seed=1, styles=["sleepy"])
    ids = [f"{i:06d}" for i in range(50)]
    splits = assign_splits(ids, 3)
    assert [len(splits[k]) for k in ("train", "val", "test")] == [40, 5, 5] and assign_splits(ids, 3) == splits


def test_styles_and_contents_are_learnable_by_a_linear_probe(one_thread: None) -> None:
    """Small version of bench/bench_synth.py: held-out style and content accuracy of a linear probe."""
    specs = plan_specs(216, seed=7, neutral_fraction=0.2)
    x = np.stack([pooled_descriptor(spec_to_clip(s, f"{i:06d}").motion) for i, s in enumerate(specs)])
    test = np.arange(len(specs)) % 4 == 0
    for key, minimum in (("style", 0.85), ("content", 0.9)):
        y = np.array([getattr(s, key) for s in specs])
        pred = linear_probe_predict(x[~test], list(y[~test]), x[test])
        accuracy = float((pred == y[test]).mean())
        assert accuracy >= minimum, f"{key} accuracy {accuracy:.2f} < {minimum}"
