"""The feature-statistics baseline method and the method registry (no Ray)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.corpus.rejects import Reject
from motionaug.augment.methods.registry import (
    create_method,
    known_methods,
    method_class,
    validate_method_params,
)
from motionaug.augment.methods.stats_baseline import StatsBaselineMethod, pose_channels
from motionaug.augment.outputs.shards import TransferOutput
from motionaug.schemas.captions import Caption
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.styles import StyleSpec

STYLE = StyleSpec.model_validate(
    {
        "name": "proud",
        "words": {"adjective": "proud", "adverb": "proudly"},
        "examples": [{"source": "x.npy", "description": "a person walks proudly"}],
    }
)


def _clip(clip_id: str, scale: float, offset: float, frames: int = 60, seed: int = 0) -> MotionClip:
    rng = np.random.default_rng(seed)
    motion = (rng.standard_normal((frames, 263)) * scale + offset).astype(np.float32)
    motion[:, 3] = 0.9  # root height
    caption = Caption(text="a person walks forward", tokens=["a/DET", "person/NOUN", "walk/VERB", "forward/ADV"])
    return MotionClip(clip_id, motion, [caption])


@pytest.fixture()
def model(tmp_path: Path):
    method = StatsBaselineMethod()
    artifact = method.prepare(STYLE, [_clip("ex", 2.0, 1.0, 80, seed=1)], None, [], tmp_path / "art").folder
    assert (artifact / "weights.safetensors").is_file() and (artifact / "artifact.json").is_file()
    return method.load(artifact, None)


def test_pose_channels_take_the_example_statistics_and_root_is_kept(model) -> None:
    clip = _clip("c", 0.5, -3.0, seed=2)
    out = model.transfer([clip], seed=0)[0]
    assert isinstance(out, TransferOutput) and out.source_id == "c" and out.style == "proud"
    pose = pose_channels()
    assert np.allclose(out.motion[:, pose].mean(axis=0), model.mean, atol=1e-4)
    assert np.allclose(out.motion[:, pose].std(axis=0), model.std, rtol=1e-3)
    kept = np.setdiff1d(np.arange(263), pose)
    assert np.array_equal(out.motion[:, kept], clip.motion[:, kept])  # root trajectory, height, contacts
    assert 0.0 <= out.scores["foot_skating"] <= 1.0
    assert out.captions and all(t.count("/") == 1 for c in out.captions for t in c.tokens)
    assert any("proud" in c.text for c in out.captions)


def test_bad_clips_come_back_as_rejects_not_exceptions(model) -> None:
    nan = _clip("nan", 1.0, 0.0)
    nan.motion[3, 10] = np.nan
    narrow = MotionClip("narrow", np.zeros((30, 100), np.float32), [Caption(text="x")])
    good = _clip("good", 1.0, 0.0)
    results = model.transfer([nan, narrow, good], seed=0)
    assert isinstance(results[0], Reject) and "NaN" in results[0].reason and results[0].id == "nan"
    assert isinstance(results[1], Reject) and "263" in results[1].reason
    assert isinstance(results[2], TransferOutput)


def test_transfer_is_deterministic(model) -> None:
    clip = _clip("c", 1.0, 0.0)
    a, b = model.transfer([clip], seed=7)[0], model.transfer([clip], seed=7)[0]
    assert a.motion.tobytes() == b.motion.tobytes() and a.captions == b.captions


def test_registry_validates_params_and_names_methods() -> None:
    assert {"stats", "onthefly"} <= set(known_methods())
    assert method_class("stats") is StatsBaselineMethod and not StatsBaselineMethod.trains
    assert validate_method_params("stats", {"strength": "0.5"}) == {"strength": 0.5, "n_variants": 1}
    with pytest.raises(MotionDataError, match=r"method.params.strength: stats: Input should be less than or equal"):
        validate_method_params("stats", {"strength": 2})
    with pytest.raises(MotionDataError, match="method.params.colour: stats: Extra inputs are not permitted"):
        create_method("stats", {"colour": 1})
    with pytest.raises(MotionDataError, match="unknown method 'nope'"):
        method_class("nope")
    assert create_method("stats", {"strength": 0.25}).params.strength == 0.25


def test_an_artefact_checksum_ignores_its_wall_clock_facts(tmp_path: Path) -> None:
    """Two artefacts that differ only in how long they took to make have the same checksum (shards cite it)."""
    from motionaug.augment.outputs.checksums import TIMINGS_FILE, sha256_tree

    for name, seconds in (("a", 1.5), ("b", 99.0)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "weights.bin").write_bytes(b"same")
        (tmp_path / name / TIMINGS_FILE).write_text(f'{{"finetune_s": {seconds}}}')
    assert sha256_tree(tmp_path / "a") == sha256_tree(tmp_path / "b") == sha256_tree(tmp_path / "a")
    (tmp_path / "b" / "weights.bin").write_bytes(b"other")
    assert sha256_tree(tmp_path / "a") != sha256_tree(tmp_path / "b")
