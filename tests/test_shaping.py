"""Which example shapes a clip, and which reference stands for each example (``augment/methods/shaping.py``)."""

from __future__ import annotations

import zlib

import numpy as np
import pytest

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.methods.hooks import OutputShaper, ShapeContext, output_shapers
from motionaug.augment.methods.shaping import example_index, read_shaping, shape, write_shaping
from motionaug.augment.motion.travel import heading, opposed, travels
from motionaug.schemas.errors import MotionDataError

FPS = 20.0


def motion(speed: float, seed: int, frames: int = 60) -> np.ndarray:
    """Features (frames, 263) of a clip moving forwards at ``speed`` m/s, the rest noise."""
    rng = np.random.default_rng(seed)
    m = rng.normal(0, 0.05, (frames, 263)).astype(np.float32)
    m[:, 1:3] = [0.0, speed / FPS]  # root_lin_vel: metres a frame in the facing frame (x, z)
    m[:, 3] = 0.95
    return m


def swaying(speed: float, seed: int) -> np.ndarray:
    """A clip whose root moves back and forth at ``speed`` m/s, a step's time each way: a squat or a dance on the
    spot."""
    m = motion(speed, seed)
    m[:, 2] *= np.where(np.arange(len(m)) // 10 % 2 == 0, 1.0, -1.0)
    return m


def test_a_clip_that_travels_is_told_apart_from_one_that_stays_in_place() -> None:
    assert travels(motion(1.2, 0), FPS) and travels(motion(2.9, 1), FPS)  # a walk, a run
    assert travels(motion(0.2, 2), FPS)  # an old person's walk
    assert not travels(motion(0.02, 3), FPS) and not travels(motion(0.05, 4), FPS)  # a wave, a shuffle on the spot
    assert not travels(swaying(0.3, 5), FPS) and not travels(swaying(1.0, 6), FPS)  # fast, but going nowhere


def test_a_clip_travelling_the_other_way_from_the_example_is_told_apart() -> None:
    backward, sideways = motion(-1.2, 4), motion(1.2, 5)
    sideways[:, 1:3] = [1.2 / FPS, 0.0]
    assert heading(motion(1.2, 0)) > 0.9 and heading(backward) < -0.9 and abs(heading(sideways)) < 0.1
    assert opposed(backward, motion(1.2, 0), FPS) and opposed(motion(1.2, 0), backward, FPS)
    assert not opposed(motion(1.3, 6), motion(1.2, 0), FPS)  # both forwards
    assert not opposed(sideways, backward, FPS)  # a sidestep goes neither way
    assert not opposed(motion(-0.05, 7), motion(1.2, 0), FPS)  # a shuffle on the spot does not travel
    assert opposed(motion(-0.2, 8), motion(1.2, 0), FPS)  # a slow walk backwards does


def test_a_clip_gets_an_example_that_moves_as_it_does_picked_by_its_id() -> None:
    ids = [f"clip_{i:03d}" for i in range(40)]
    walks_and_a_wave = [True, True, False]
    for clip_id in ids:
        assert example_index(clip_id, False, walks_and_a_wave) == 2  # the only in-place example
        assert example_index(clip_id, True, walks_and_a_wave) in (0, 1)
        # where every example moves alike (or none like the clip), the pick is the id's alone, as it always was
        assert example_index(clip_id, False, [True] * 3) == zlib.crc32(clip_id.encode()) % 3
        assert example_index(clip_id, True, [True] * 3) == zlib.crc32(clip_id.encode()) % 3
    assert {example_index(i, True, walks_and_a_wave) for i in ids} == {0, 1}  # both walks get used


def test_shape_uses_the_in_place_example_for_an_in_place_clip() -> None:
    walk, wave = motion(1.2, 10), motion(0.02, 11) * 1.5
    walk_reference, wave_reference = motion(1.0, 12), motion(0.03, 13)
    steps = output_shapers.create_all(["moments"])
    for clip_id in ("a", "b", "c", "d"):
        content = MotionClip(clip_id, motion(0.02, 14), [], FPS)
        both = shape(content.motion, content, steps, [walk, wave], [walk_reference, wave_reference])
        alone = shape(content.motion, content, steps, [wave], [wave_reference])
        np.testing.assert_array_equal(both, alone)


def test_a_shaper_sees_every_example_alike_the_clip_with_its_reference() -> None:
    class Seen(OutputShaper):
        def __init__(self) -> None:
            self.contexts: list[ShapeContext] = []

        def __call__(self, output: np.ndarray, context: ShapeContext) -> np.ndarray:
            self.contexts.append(context)
            return output

    walks, wave = [motion(1.2, 40), motion(1.1, 41)], motion(0.02, 42)
    references = [motion(1.0, 43), motion(1.0, 44), motion(0.03, 45)]
    seen = Seen()
    for speed, expected in ((1.3, [0, 1]), (0.01, [2])):
        content = MotionClip("clip", motion(speed, 46), [], FPS)
        shape(content.motion, content, [seen], [*walks, wave], references)
        alike = seen.contexts[-1].alike
        assert len(alike) == len(expected)
        for (example, reference), i in zip(alike, expected):
            assert example is [*walks, wave][i] and reference is references[i]
        assert any(example is seen.contexts[-1].example for example, _ in alike)  # the picked one is among them


def test_a_named_reference_stands_for_its_example_and_a_bad_one_is_refused(tmp_path) -> None:
    examples = [MotionClip("ex_walk", motion(1.2, 20), []), MotionClip("ex_wave", motion(0.0, 21), [])]
    pool = [MotionClip(f"pool_{i}", motion(1.0 + 0.1 * i, 30 + i), []) for i in range(4)]
    plain_wave = MotionClip("plain_wave", motion(0.01, 40), [])
    write_shaping(tmp_path, "elderly", examples, pool, ["moments"], [None, plain_wave])
    _, references = read_shaping(tmp_path)
    np.testing.assert_array_equal(references[1], plain_wave.motion)  # the user's, not the pool's nearest walk
    assert any(np.array_equal(references[0], c.motion) for c in pool)  # none named: the pool's nearest
    # the named references cover every example, so no pool is needed
    write_shaping(tmp_path, "elderly", examples[1:], [], ["moments"], [plain_wave])
    short = MotionClip("too_short", motion(0.0, 41, frames=3), [])
    with pytest.raises(MotionDataError, match="reference 'too_short'.*not a usable reference"):
        write_shaping(tmp_path, "elderly", examples[1:], pool, ["moments"], [short])
    with pytest.raises(MotionDataError, match="need usable plain pool clips"):
        write_shaping(tmp_path, "elderly", examples, [], ["moments"], [None, plain_wave])
