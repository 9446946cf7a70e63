"""The protocol's judges: what each reads, that the second style judge cannot be moved by the moment rule, and
that trained judges save, load, read real held-out clips and name their fit (the fingerprint the LSO gather prints),
the same fit on another CPU under the pinned numerics."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import load_bench

from motionaug.augment.corpus import Corpus
from motionaug.augment.eval.judges import JUDGES, fit_judges, judge_input, load_judges, motion_channels
from motionaug.augment.eval.numerics import pinned_env
from motionaug.augment.methods.hooks import ShapeContext, output_shapers
from motionaug.augment.motion.batch import pad_batch
from motionaug.augment.motion.features import Normalizer
from motionaug.augment.synth import generate_corpus
from motionaug.models.evaluators import make_classifier
from motionaug.schemas.skeleton import T2M

FIXTURES = Path(__file__).resolve().parent / "fixtures" / "humanml3d"


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("judges") / "corpus"
    generate_corpus(root, 48, seed=1, styles=["neutral", "proud", "old"], contents=["walk", "run"])
    return root


# One judge fit in a fresh process (CPU numerics are fixed at its start), pinned or not; prints its fingerprint.
FIT = """
import contextlib, sys
from pathlib import Path
import torch
from motionaug.augment.corpus import Corpus
from motionaug.augment.eval.judges import fit_judges
from motionaug.augment.eval.numerics import pinned_kernels

torch.set_num_threads(1)
train = list(Corpus(Path(sys.argv[1]), split="train"))
with pinned_kernels() if sys.argv[3] == "pinned" else contextlib.nullcontext():
    judges = fit_judges(train, Path(sys.argv[2]), epochs=2, size="tiny", which=("style", "style_clip"))
print(judges.fingerprint)
"""
# Another CPU, as far as one machine can show it: oneDNN and MKL held to AVX2, as on a CPU without AVX-512
CAPPED = {"ONEDNN_MAX_CPU_ISA": "AVX2", "MKL_ENABLE_INSTRUCTIONS": "AVX2"}


def fit_in_fresh_process(corpus: Path, out: Path, env: dict[str, str], how: str) -> str:
    cmd = [sys.executable, "-c", FIT, str(corpus), str(out), how]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout.split()[-1]


def moment_rule(content: np.ndarray, example: np.ndarray, reference: np.ndarray, norm: Normalizer) -> np.ndarray:
    """The shipped ``moments`` shaper (posture and amplitude from an example against its plain reference) on the
    content clip itself."""
    c, e, r = (norm.normalize(x) for x in (content, example, reference))
    shaped = output_shapers.create("moments")(c, ShapeContext(content=c, example=e, reference=r, fps=20.0))
    return norm.denormalize(shaped)


def test_judge_channels_are_facing_frame_positions_velocities_and_root_motion() -> None:
    clip = np.load(FIXTURES / "new_joint_vecs" / "012314.npy")
    style, content = motion_channels(clip, with_root=True), motion_channels(clip, with_root=False)
    assert style.shape == (170, 6 * 22 + 4) and content.shape == (170, 6 * 22)
    np.testing.assert_array_equal(style[:, : 6 * 22], content)
    np.testing.assert_allclose(style[:, 1], clip[:, 3])  # the root's height
    np.testing.assert_allclose(style[1:, 66:69], (style[1:, :3] - style[:-1, :3]) * 20.0, atol=1e-5)
    assert judge_input("style", clip, 196).shape == (170, 22, 3)


def test_the_second_style_judge_is_blind_to_the_moment_rule(corpus: Path) -> None:
    """Setting channel means and variances from an example (the moment rule) moves judge 1, not judge 2."""
    norm = Normalizer(np.load(FIXTURES / "Mean.npy"), np.load(FIXTURES / "Std.npy"))
    content = np.load(FIXTURES / "new_joint_vecs" / "012314.npy")
    clips = list(Corpus(corpus))
    example = next(c.motion for c in clips if c.style == "old" and c.content == "walk")
    reference = next(c.motion for c in clips if c.style == "neutral")
    shaped = moment_rule(content, example, reference, norm)
    assert np.abs(shaped - content).max() > 0.05  # the rule changes the clip
    torch.manual_seed(0)
    for name, moved in (("style_clip", False), ("style", True)):
        width = {"style_clip": {"in_channels": 136, "standardise": "clip"}, "style": {}}[name]
        judge = make_classifier(2, T2M.n_joints, "tiny", **width).eval()
        judge.set_input_stats(*pad_batch([judge_input(name, c.motion, 196) for c in clips]))
        before, after = (judge(*pad_batch([judge_input(name, m, 196)])) for m in (content, shaped))
        change = float((before - after).abs().max())
        assert (change > 1e-2) if moved else (change < 1e-4), (name, change)


def test_judges_fit_save_load_and_report_held_out_accuracy(corpus: Path, tmp_path: Path) -> None:
    train, test = list(Corpus(corpus, split="train")), list(Corpus(corpus, split="test"))
    judges = fit_judges(train, tmp_path / "judges", epochs=3, size="tiny", held_out=test)
    assert judges.info.trained_on == sorted(c.id for c in train)
    assert set(judges.info.accuracy) == set(JUDGES) and all("all" in a for a in judges.info.accuracy.values())
    loaded = load_judges(tmp_path / "judges")
    for name in JUDGES:
        pred, feats = judges.predict(name, [c.motion for c in test])
        pred2, feats2 = loaded.predict(name, [c.motion for c in test])
        np.testing.assert_array_equal(pred, pred2)
        np.testing.assert_allclose(feats, feats2, atol=1e-6)
    assert loaded.labels("style") == ["neutral", "old", "proud"]
    # the fingerprint names the fit: kept through save and load, changed by any weight
    assert loaded.fingerprint == judges.fingerprint and len(judges.fingerprint) == 12
    with torch.no_grad():
        next(loaded.models["content_pose"].parameters()).view(-1)[0] += 1e-6
    assert loaded.fingerprint != judges.fingerprint


def test_the_lso_gather_names_the_judge_fit_of_each_row() -> None:
    lso = load_bench("bench_lso")
    mixed = lso.judges_note({"erd": [{"judges": "a1"}, {"judges": "a1"}], "content": [{"units": []}]})
    assert mixed == "judges (several fits: compare rows under one fit only): a1: erd; unrecorded: content"
    assert lso.judges_note({"erd": [{"judges": "a1"}], "moments": [{"judges": "a1"}]}) == "judges: a1: erd, moments"


def test_pinned_judges_fit_the_same_weights_on_another_cpu(corpus: Path, tmp_path: Path) -> None:
    """Under the pinned numerics, a fit with the kernels of a CPU without AVX-512 gives this CPU's weights bit for bit
    (unpinned, oneDNN's AVX-512 and AVX2 convolutions sum in other orders and the weights differ)."""
    capability = torch.backends.cpu.get_cpu_capability()
    if capability not in ("AVX2", "AVX512"):
        pytest.skip(f"the pinned numerics need an x86-64 CPU with AVX2 (ATen runs {capability} kernels here)")
    capped = {**os.environ, **CAPPED}
    here = fit_in_fresh_process(corpus, tmp_path / "here", pinned_env(), "pinned")
    there = fit_in_fresh_process(corpus, tmp_path / "there", pinned_env(capped), "pinned")
    assert here == there
    if capability == "AVX512":  # the capped process is another CPU indeed: unpinned, its fit differs
        free = fit_in_fresh_process(corpus, tmp_path / "free", dict(os.environ), "free")
        assert free != fit_in_fresh_process(corpus, tmp_path / "free-capped", capped, "free")
