"""HumanML3D folders: lazy reading, caption-span cuts, one reject per bad input, byte-stable writing."""

from __future__ import annotations

import hashlib
import inspect
import shutil
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from conftest import FIXTURES, require_shared

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.corpus.humanml3d import HumanML3DReader, span_id, write_humanml3d
from motionaug.schemas.captions import Caption
from motionaug.schemas.errors import MotionDataError

FIXTURE = FIXTURES / "corpus" / "humanml3d"
WIDTH = 263
# Frames per fixture id: 000001 has a 1.0-4.0 s span, 000002 only a 0.5-2.5 s span, 012314 a 0.0-2.0 s span.
LENGTHS = {
    "000001": 120,
    "000002": 60,
    "000003": 45,
    "012314": 170,
    "M000001": 120,
    "M000002": 60,
    "M000003": 45,
    "M012314": 170,
    "004822": 80,
    "014457": 199,
}
# What the fixture yields: every id's whole clip except 000002 (span captions only), plus three cuts.
EXPECTED_IDS = [
    "000001",
    "000001_0100_0400",
    "000002_0050_0250",
    "000003",
    "012314",
    "012314_0000_0200",
    "M000001",
    "M000002",
    "M000003",
    "M012314",
    "004822",
    "014457",
]


def motion_for(clip_id: str, n_frames: int) -> np.ndarray:
    """Random features, seeded by the id, so a test can recompute what a file holds."""
    seed = int(hashlib.sha256(clip_id.encode()).hexdigest()[:8], 16)
    return np.random.default_rng(seed).standard_normal((n_frames, WIDTH)).astype(np.float32)


@pytest.fixture
def corpus(tmp_path: Path) -> Path:
    root = tmp_path / "humanml3d"
    shutil.copytree(FIXTURE, root)
    (root / "new_joint_vecs").mkdir()
    for clip_id, n_frames in LENGTHS.items():
        np.save(root / "new_joint_vecs" / f"{clip_id}.npy", motion_for(clip_id, n_frames))
    return root


def test_reads_fixture_with_span_cuts(corpus: Path) -> None:
    reader = HumanML3DReader(corpus)
    clips = {clip.id: clip for clip in reader}
    assert list(clips) == EXPECTED_IDS and reader.rejects == []
    assert reader.ids() == list(LENGTHS)[:8] + ["004822", "014457"]
    whole = clips["000001"]
    assert (
        whole.motion.dtype == np.float32
        and whole.motion.flags.writeable
        and np.array_equal(whole.motion, motion_for("000001", 120))
    )
    assert [c.text for c in whole.captions] == [
        "a man kicks something with his left leg.",
        "a person kicks forward with the left foot.",
    ]
    cut = clips[span_id("000001", 1.0, 4.0)]
    assert np.array_equal(cut.motion, motion_for("000001", 120)[20:80])  # frames [int(1.0*20), int(4.0*20))
    assert [(c.text, c.start, c.end) for c in cut.captions] == [("someone steps back after kicking.", 0.0, 0.0)]
    assert cut.meta == {"parent": "000001", "span": "1.0-4.0"}
    # Two captions sharing one span share one cut; a file with only span captions yields no whole clip.
    assert len(clips["000002_0050_0250"].captions) == 2 and "000002" not in clips
    # NaN start/end reads as the whole clip, as in the reference loader; the blank line is ignored.
    assert [c.text for c in clips["012314"].captions][1] == "a man hops in place."
    assert clips["012314_0000_0200"].n_frames == 40


def test_split_and_every_npy(corpus: Path) -> None:
    test_ids = [clip.id for clip in HumanML3DReader(corpus, split="test")]
    assert test_ids == ["004822", "014457"]
    assert all(clip.meta == {"split": "test"} for clip in HumanML3DReader(corpus, split="test"))
    assert len(list(HumanML3DReader(corpus, split=None))) == len(EXPECTED_IDS)
    with pytest.raises(MotionDataError, match="val.txt: split file is missing"):
        HumanML3DReader(corpus, split="val")


def test_length_filter_rejects_files_then_cuts(corpus: Path) -> None:
    reader = HumanML3DReader(corpus, min_frames=40, max_frames=169)
    ids = [clip.id for clip in reader]
    rejected = {r.id: r.reason for r in reader.rejects}
    assert rejected == {
        "012314": "170 frames, more than max_frames=169",
        "M012314": "170 frames, more than max_frames=169",
        "014457": "199 frames, more than max_frames=169",
    }
    assert "012314_0000_0200" not in ids  # the reference drops a too-long file before looking at its spans
    reader = HumanML3DReader(corpus, min_frames=50)
    ids = [clip.id for clip in reader]
    assert {r.id for r in reader.rejects} == {"000002_0050_0250", "000003", "M000003", "012314_0000_0200"}
    assert "000001_0100_0400" in ids


def test_split_spans_off_keeps_every_caption_on_its_file(corpus: Path) -> None:
    clips = {clip.id: clip for clip in HumanML3DReader(corpus, split_spans=False)}
    assert len(clips) == len(LENGTHS)
    assert [(c.start, c.end) for c in clips["000002"].captions] == [(0.5, 2.5), (0.5, 2.5)]


def _truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[:-1000])


def _garbage(path: Path) -> None:
    path.write_bytes(b"this is not a numpy file at all")


def _narrow(path: Path) -> None:
    np.save(path, np.zeros((60, 250), np.float32))


def _nan_at_frame_7(path: Path) -> None:
    motion = np.load(path)
    motion[7, 3] = np.nan
    motion[9, 0] = np.inf
    np.save(path, motion)


def _no_frames(path: Path) -> None:
    np.save(path, np.zeros((0, WIDTH), np.float32))


def _strings(path: Path) -> None:
    np.save(path, np.array([["a"] * WIDTH]))


@pytest.mark.parametrize(
    ("damage", "reason"),
    [
        (_truncate, "truncated .npy"),
        (_garbage, "not a readable .npy file"),
        (_narrow, "feature width 250, expected 263"),
        (_nan_at_frame_7, "NaN/Inf values from frame 7 (2 bad frames)"),
        (_no_frames, "motion has no frames"),
        (_strings, "expected floating point"),
        (Path.unlink, "missing, though"),
    ],
)
def test_bad_motion_file_is_one_reject(corpus: Path, damage, reason: str) -> None:
    damage(corpus / "new_joint_vecs" / "000003.npy")
    reader = HumanML3DReader(corpus)
    ids = [clip.id for clip in reader]
    assert ids == [i for i in EXPECTED_IDS if i != "000003"]
    [reject] = reader.rejects
    assert reject.id == "000003" and reject.source.endswith("new_joint_vecs/000003.npy")
    assert reason in reject.reason
    with pytest.raises(MotionDataError, match="000003.npy"):
        list(HumanML3DReader(corpus, on_error="raise"))


@pytest.mark.parametrize(
    ("text", "source_end", "reason"),
    [
        (None, "texts/M000003.txt", "caption file is missing"),
        ("\n\n", "texts/M000003.txt", "caption file has no captions"),
        (
            "a person walks.#a/DET person/NOUN walk/VERB#0.0#0.0\nbroken line#walk/VERB\n",
            "texts/M000003.txt:2",
            "found 2",
        ),
        ("a person walks.#a/DET person/NOUN walk#0.0#0.0\n", "texts/M000003.txt:1", "'walk' is not 'word/POS'"),
        (b"caf\xe9 walk#walk/VERB#0.0#0.0\n", "texts/M000003.txt", "not UTF-8"),
    ],
)
def test_bad_caption_file_is_one_reject(corpus: Path, text: str | bytes | None, source_end: str, reason: str) -> None:
    path = corpus / "texts" / "M000003.txt"
    if text is None:
        path.unlink()
    elif isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text)
    reader = HumanML3DReader(corpus)
    assert [clip.id for clip in reader] == [i for i in EXPECTED_IDS if i != "M000003"]
    [reject] = reader.rejects
    assert (reject.id, reject.source.endswith(source_end)) == ("M000003", True)
    assert reason in reject.reason


def test_empty_caption_span_is_a_reject_for_the_cut(corpus: Path) -> None:
    with open(corpus / "texts" / "000003.txt", "a") as handle:
        handle.write("a person stops.#a/DET person/NOUN stop/VERB#5.0#4.0\n")
    reader = HumanML3DReader(corpus)
    assert len(list(reader)) == len(EXPECTED_IDS)
    [reject] = reader.rejects
    assert reject.id == "000003_0500_0400" and "span 5.0-4.0 s is empty in 45 frames" in reject.reason


def test_cut_id_collision_is_a_reject(corpus: Path) -> None:
    with open(corpus / "texts" / "000001.txt", "a") as handle:
        handle.write("someone steps back.#someone/PRON step/VERB back/ADV#1.001#4.0\n")  # rounds to 000001_0100_0400
    reader = HumanML3DReader(corpus)
    assert [clip.id for clip in reader] == EXPECTED_IDS
    [reject] = reader.rejects
    assert reject.id == "000001_0100_0400" and "duplicate id" in reject.reason


def test_unsafe_and_duplicate_ids_are_rejected_without_touching_paths(corpus: Path) -> None:
    outside = corpus.parent / "secret"
    (outside / "new_joint_vecs").mkdir(parents=True)
    np.save(outside / "new_joint_vecs" / "x.npy", motion_for("x", 50))  # a valid clip the id would reach
    with open(corpus / "all.txt", "a") as handle:
        handle.write("../secret/new_joint_vecs/x\n.hidden\n000003\n")
    reader = HumanML3DReader(corpus)
    assert [clip.id for clip in reader] == EXPECTED_IDS
    rejects = {r.id: r for r in reader.rejects}
    assert set(rejects) == {"../secret/new_joint_vecs/x", ".hidden", "000003"}
    assert rejects["../secret/new_joint_vecs/x"].reason.startswith("unsafe id")
    assert rejects["../secret/new_joint_vecs/x"].source.endswith("all.txt:11")
    assert rejects[".hidden"].reason.startswith("unsafe id")
    assert rejects["000003"].reason == "duplicate id '000003'"
    with pytest.raises(MotionDataError, match="unsafe id"):
        HumanML3DReader(corpus, split="../all")
    (corpus / "test.txt").write_bytes(b"004822\n\xff\xfe\n")
    with pytest.raises(MotionDataError, match="test.txt: not UTF-8 text"):
        list(HumanML3DReader(corpus, split="test"))  # a corrupt split file is not a per-clip problem


def test_reader_is_lazy(corpus: Path) -> None:
    npys = sorted((corpus / "new_joint_vecs").iterdir())
    moved = corpus.parent / "moved"
    shutil.move(corpus / "new_joint_vecs", moved)
    (corpus / "new_joint_vecs").mkdir()
    reader = HumanML3DReader(corpus)  # no clip file exists yet: construction must not read any
    for npy in npys:
        shutil.move(moved / npy.name, npy)
    clips = iter(reader)
    assert inspect.isgenerator(clips)
    assert next(clips).id == "000001"
    _garbage(corpus / "new_joint_vecs" / "014457.npy")  # damaged after the pass began, before it got there
    assert [clip.id for clip in clips][-1] == "004822"
    assert [r.id for r in reader.rejects] == ["014457"]


def test_reader_memory_is_one_clip(tmp_path: Path) -> None:
    root = tmp_path / "big"
    (root / "new_joint_vecs").mkdir(parents=True)
    (root / "texts").mkdir()
    n_clips, n_frames = 40, 199
    for i in range(n_clips):
        np.save(root / "new_joint_vecs" / f"{i:06d}.npy", motion_for(str(i), n_frames))
        (root / "texts" / f"{i:06d}.txt").write_text("a person walks.#a/DET person/NOUN walk/VERB#0.0#0.0\n")
    clip_bytes = n_frames * WIDTH * 4
    tracemalloc.start()
    frames = sum(clip.n_frames for clip in HumanML3DReader(root, split=None))
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert frames == n_clips * n_frames
    assert peak < 4 * clip_bytes, f"peak {peak} bytes for {n_clips} clips of {clip_bytes} bytes"


def test_mean_std(corpus: Path) -> None:
    np.save(corpus / "Mean.npy", np.arange(WIDTH, dtype=np.float32))
    np.save(corpus / "Std.npy", np.ones(WIDTH, dtype=np.float64))
    mean, std = HumanML3DReader(corpus).mean_std()
    assert mean.dtype == std.dtype == np.float32 and mean[5] == 5 and std.shape == (WIDTH,)
    np.save(corpus / "Std.npy", np.ones(WIDTH - 1, dtype=np.float32))
    with pytest.raises(MotionDataError, match="Std.npy: feature width 262, expected 263"):
        HumanML3DReader(corpus).mean_std()


def _tree_digest(root: Path) -> dict[str, str]:
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def test_write_read_round_trip_is_byte_stable(corpus: Path, tmp_path: Path) -> None:
    clips = list(HumanML3DReader(corpus))
    out = tmp_path / "out"
    splits = {"train": [clip.id for clip in clips[:4]], "test": [clips[-1].id]}
    mean_std = (np.zeros(WIDTH, np.float32), np.ones(WIDTH, np.float32))
    assert write_humanml3d(clips, out, splits=splits, mean_std=mean_std) == EXPECTED_IDS
    first = _tree_digest(out)
    assert "Mean.npy" in first and "texts/000001_0100_0400.txt" in first and len(first) == 2 * len(clips) + 6
    reader = HumanML3DReader(out)
    back = list(reader)
    assert reader.rejects == [] and [c.id for c in back] == [c.id for c in clips]
    for a, b in zip(clips, back):
        assert np.array_equal(a.motion, b.motion) and a.captions == b.captions and a.meta == b.meta
    assert [c.id for c in HumanML3DReader(out, split="test")] == [clips[-1].id]
    write_humanml3d(back, out, splits=splits, mean_std=mean_std)
    assert _tree_digest(out) == first
    assert not list(out.rglob("*.tmp"))


def _clip(clip_id: str, text: str = "a person runs.", fps: float = 20.0) -> MotionClip:
    return MotionClip(clip_id, motion_for(clip_id, 50), [Caption(text=text, tokens=["run/VERB"])], fps=fps)


@pytest.mark.parametrize(
    ("clips", "splits", "message"),
    [
        ([_clip("a/../../b")], None, "clip 'a/../../b': unsafe id"),
        ([_clip("a"), _clip("a")], None, "clip 'a': duplicate id"),
        ([_clip("a", text="run #1")], None, "contains '#'"),
        ([_clip("a", fps=30.0)], None, "fps 30.0, but this HumanML3D folder is 20.0 fps"),
        ([MotionClip("a", motion_for("a", 50), [])], None, "no captions"),
        ([MotionClip("a", np.zeros((5, 263, 1), np.float32), [])], None, "shape (5, 263, 1)"),
        ([_clip("a")], {"train": ["a", "zz"]}, "split 'train': 1 ids were not written, e.g. 'zz'"),
        ([_clip("a")], {"../train": ["a"]}, "unsafe id '../train'"),
    ],
)
def test_write_refuses_bad_clips(tmp_path: Path, clips, splits, message: str) -> None:
    with pytest.raises(MotionDataError) as info:
        write_humanml3d(clips, tmp_path / "out", splits=splits)
    assert message in str(info.value)
    assert not (tmp_path / "b.npy").exists() and not list(tmp_path.rglob("*.tmp"))


def test_real_clip_and_split_files(tmp_path: Path) -> None:
    sample = require_shared("humanml3d_sample")
    root = tmp_path / "real"
    (root / "new_joint_vecs").mkdir(parents=True)
    (root / "texts").mkdir()
    shutil.copy(sample / "new_joint_vecs" / "012314.npy", root / "new_joint_vecs")
    for name in ("Mean.npy", "Std.npy", "train.txt"):
        shutil.copy(sample / name, root)
    shutil.copy(FIXTURE / "texts" / "012314.txt", root / "texts")
    reader = HumanML3DReader(root, split=None)
    [clip, cut] = list(reader)
    assert np.array_equal(clip.motion, np.load(sample / "new_joint_vecs" / "012314.npy")) and clip.n_frames == 170
    assert cut.id == "012314_0000_0200" and cut.n_frames == 40
    mean, std = reader.mean_std()
    assert mean.shape == std.shape == (263,) and bool((std > 0).all())
    # Every id of the real training split passes the id check; only 012314 and its mirror are present here.
    train = HumanML3DReader(root, split="train")
    assert len(train.ids()) == 23384
    assert [c.id for c in train] == ["012314", "012314_0000_0200"]
    assert len(train.rejects) == 23384 - 1 and all(r.reason.startswith("missing, though") for r in train.rejects)


def test_labels_sidecar_round_trip(tmp_path: Path) -> None:
    clips = [_clip("a1"), _clip("a2")]
    clips[0].content, clips[0].style, clips[0].meta = "run", "proud", {"spec": "{}"}
    write_humanml3d(clips, tmp_path)
    back = {c.id: c for c in HumanML3DReader(tmp_path)}
    assert (back["a1"].content, back["a1"].style, back["a1"].meta) == ("run", "proud", {"spec": "{}"})
    assert back["a2"].content is None and back["a2"].style is None


def test_corrupt_labels_sidecar_is_named(tmp_path: Path) -> None:
    write_humanml3d([_clip("a1")], tmp_path)
    (tmp_path / "labels.jsonl").write_text("{not json\n")
    with pytest.raises(MotionDataError, match=r"labels.jsonl:1"):
        list(HumanML3DReader(tmp_path))


def test_a_clip_read_through_another_split_file_keeps_its_standard_split() -> None:
    from motionaug.augment.corpus import Corpus

    def clip(clip_id: str, split: str | None, parent: str | None = None) -> MotionClip:
        meta = {k: v for k, v in (("split", split), ("parent", parent)) if v is not None}
        return MotionClip(clip_id, np.zeros((40, 263), np.float32), [], meta=meta)

    files = {"000001": "train", "000002": "test"}
    assert Corpus.split_of(clip("000001", "expand"), files) == "train"  # read through expand.txt
    assert Corpus.split_of(clip("000002#1", "expand", parent="000002"), files) == "test"
    assert Corpus.split_of(clip("000003", "expand"), files) == "expand"  # no standard split lists it
    assert Corpus.split_of(clip("000001", "val"), files) == "val"  # a row's own standard split wins
