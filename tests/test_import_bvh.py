"""BVH import as a training-ready corpus: label captions, clip cutting, take splits, train Mean/Std, licence,
and a corpus MDM's own loader (``Text2MotionDatasetV2``) accepts. Synthetic Bandai-style takes are written from the
Bandai fixture in tests/fixtures/bvh; one test reads the real dataset-2 from ../shared/data."""

from __future__ import annotations

import json
import math
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from motionaug.augment.corpus.humanml3d import HumanML3DReader, read_labels
from motionaug.augment.corpus.import_bvh import (
    BANDAI2_CLIP_FRAMES,
    BANDAI_LICENCE,
    MDM_MIN_FRAMES,
    TOO_SHORT_FILE,
    auto_takes,
    corpus_licence,
    cut_bounds,
    import_bvh,
    iter_bvh_clips,
    split_takes,
)
from motionaug.augment.corpus.parquet import read_parquet_corpus
from motionaug.augment.motion.features import compute_mean_std
from motionaug.augment.motion.retarget import JointMap
from motionaug.augment.synth.styles import STYLE_WORDS
from motionaug.augment.text.caption_revision import caption_words, has_style_words, neutralise_caption, revise_caption
from motionaug.augment.text.label_captions import (
    CONTENT_PHRASES,
    LABEL_STYLES,
    all_label_captions,
    is_neutral,
    label_caption,
    label_captions,
    label_key,
    label_style_words,
    neutralising_vocab,
)
from motionaug.augment.text.tokens import parse_token
from motionaug.schemas.captions import Caption
from motionaug.schemas.errors import MotionDataError

SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
FIXTURES = Path(__file__).resolve().parent / "fixtures" / "bvh"
TEMPLATE = FIXTURES / "dataset-2" / "data" / "dataset-2_raise-up-left-hand_active_003.bvh"
LEMMATISED = {"NOUN", "VERB"}  # HumanML3D lemmatises only these; other tokens spell their word


def require_shared_data(*parts: str) -> Path:
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        message = f"{path} is absent (the project's ../shared/data)"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(message)
        pytest.skip(message)
    return path


def cfg_labels(dataset: str, kind: str) -> list[str]:
    lines = (FIXTURES / dataset / "cfg" / f"{kind}_label.txt").read_text(encoding="utf-8").split()
    return [line.partition("_")[2] for line in lines]


CONTENTS = {d: cfg_labels(d, "content") for d in ("dataset-1", "dataset-2")}
STYLES = {d: cfg_labels(d, "style") for d in ("dataset-1", "dataset-2")}
PAIRS = [(c, s) for d in CONTENTS for c in CONTENTS[d] for s in STYLES[d]]
VOCAB = neutralising_vocab(STYLE_WORDS)
WORDS = label_style_words()


# ---- captions ---------------------------------------------------------------------------------------------------


def assert_humanml3d_tokens(caption: Caption) -> None:
    """One valid token per counted word; only NOUN/VERB carry lemmas; at most MDM's 20 tokens."""
    words = caption_words(caption.text)
    assert len(caption.tokens) == len(words), (caption.text, caption.tokens)
    assert len(caption.tokens) <= 20, caption.text
    assert caption.text.endswith(".") and caption.start == caption.end == 0.0
    for word, item in zip(words, caption.tokens, strict=True):
        lemma, pos = parse_token(item, caption.text)
        if pos in LEMMATISED:
            assert word.startswith(lemma[:3]) or word.startswith(lemma[:-1]), (caption.text, item)
        else:
            assert lemma == word, (caption.text, item)


def test_every_bandai_label_has_a_table_entry() -> None:
    for content in CONTENTS["dataset-1"] + CONTENTS["dataset-2"]:
        assert label_key(content) in CONTENT_PHRASES, content
    for style in STYLES["dataset-1"] + STYLES["dataset-2"]:
        assert is_neutral(style) or label_key(style) in LABEL_STYLES, style


@pytest.mark.parametrize(("content", "style"), PAIRS)
def test_captions_are_valid_humanml3d_lines(content: str, style: str) -> None:
    captions = all_label_captions(content, style)
    assert len(captions) >= 3
    for caption in captions:
        assert_humanml3d_tokens(caption)
        assert not re.search(r"\ba [aeiou]|\ban [^aeiou]", caption.text), caption.text  # articles agree
        assert not re.search(r"person .*like an? \w+ person", caption.text), caption.text


def test_captions_read_like_a_person_wrote_them() -> None:
    plain = label_caption("walk-turn-right", "normal")
    assert plain.text == "a person walks and turns right."
    assert plain.tokens == ["a/DET", "person/NOUN", "walk/VERB", "and/CCONJ", "turn/VERB", "right/ADV"]
    texts = {c.text: c for c in all_label_captions("raise-up-both-hands", "normal")}
    assert "someone raises both hands." in texts
    assert texts["someone is raising both hands."].tokens == [
        "someone/PRON",
        "is/AUX",
        "raise/VERB",
        "both/DET",
        "hand/NOUN",
    ]
    running = {c.text: c.tokens for c in all_label_captions("run", "exhausted")}
    assert running["a person is running, exhausted."] == ["a/DET", "person/NOUN", "is/AUX", "run/VERB", "exhausted/ADJ"]
    assert "a person runs in an exhausted way." in running
    assert "a person runs forward wearily." in running
    assert label_caption("wave-left-hand", "elderly").text == "an elderly person waves the left hand."
    assert label_caption("walk", "active").text == "an active person walks forward."
    assert label_caption("walk", "youthful").text == "a youthful person walks forward."
    assert "someone walks forward like an elderly person." in {c.text for c in all_label_captions("walk", "elderly")}
    assert label_caption("kick", "chimpira").text == "a thuggish person kicks."  # dataset-1
    unknown = label_caption("cartwheel", "very_sleepy")  # unknown labels still give valid captions
    assert unknown.text == "a very sleepy person performs a cartwheel motion."
    assert_humanml3d_tokens(unknown)


def test_neutral_style_is_left_out() -> None:
    for content in CONTENTS["dataset-2"]:
        captions = all_label_captions(content, "normal")
        assert [c.text for c in captions] == [c.text for c in all_label_captions(content, "neutral")]
        assert [c.text for c in captions] == [c.text for c in all_label_captions(content, None)]
        for caption in captions:
            assert "normal" not in caption.text and "neutral" not in caption.text
            assert not has_style_words(caption, VOCAB)


@pytest.mark.parametrize("style", sorted(LABEL_STYLES))
def test_every_style_wording_is_removable(style: str) -> None:
    """Each styled caption names its style, and neutralising it gives one of the neutral captions back."""
    for content in ("walk-turn-left", "raise-up-right-hand", "run"):
        neutral = {c.text for c in all_label_captions(content, "normal")}
        for caption in all_label_captions(content, style):
            assert has_style_words(caption, VOCAB), caption.text
            assert neutralise_caption(caption, VOCAB).text in neutral, caption.text


def test_label_captions_are_several_distinct_and_seeded() -> None:
    first = label_captions("walk", "elderly", n=3, seed="dataset-2_walk_elderly_001")
    assert len(first) == 3 and len({c.text for c in first}) == 3
    assert first == label_captions("walk", "elderly", n=3, seed="dataset-2_walk_elderly_001")
    seeds = {tuple(c.text for c in label_captions("walk", "elderly", seed=i)) for i in range(10)}
    assert len(seeds) > 3
    assert len(label_captions("run", "normal", n=50)) == len(all_label_captions("run", "normal"))
    with pytest.raises(ValueError):
        label_captions("run", "normal", n=0)


def test_caption_revision_inserts_style_words_after_verbs() -> None:
    walk = revise_caption(label_caption("walk", "normal"), WORDS["active"], "adverb", vocab=VOCAB)
    assert walk.text == "a person walks energetically forward."
    assert walk.tokens[2:4] == ["walk/VERB", "energetically/ADV"]
    turn = revise_caption(label_caption("walk-turn-right", "normal"), WORDS["exhausted"], "adverb", vocab=VOCAB)
    assert turn.text == "a person walks wearily and turns wearily right."
    assert turn.tokens == [
        "a/DET", "person/NOUN", "walk/VERB", "wearily/ADV", "and/CCONJ", "turn/VERB", "wearily/ADV", "right/ADV",
    ]  # fmt: skip
    comma = Caption(
        text="a person is running, exhausted.", tokens=["a/DET", "person/NOUN", "is/AUX", "run/VERB", "exhausted/ADJ"]
    )
    restyled = revise_caption(comma, WORDS["youthful"], "adverb", vocab=VOCAB)
    assert restyled.text == "a person is running youthfully."
    assert restyled.tokens == ["a/DET", "person/NOUN", "is/AUX", "run/VERB", "youthfully/ADV"]
    for caption in all_label_captions("walk", "elderly"):  # one label style into another: old words out, new in
        revised = revise_caption(caption, WORDS["youthful"], "adverb", vocab=VOCAB)
        assert "elderly" not in revised.text and " old " not in revised.text, revised.text
        assert "walk/VERB" in revised.tokens and "youthfully/ADV" in revised.tokens, revised.text
        assert revised.tokens[revised.tokens.index("walk/VERB") + 1] == "youthfully/ADV", revised.text
        assert_humanml3d_tokens(revised)


# ---- cutting and splitting ----------------------------------------------------------------------------------------


def test_cut_bounds_are_equal_contiguous_and_unpadded() -> None:
    assert cut_bounds(196, 196) == [(0, 196)]
    assert cut_bounds(197, 196) == [(0, 99), (99, 197)]
    assert cut_bounds(392, 196) == [(0, 196), (196, 392)]
    assert cut_bounds(393, 196) == [(0, 131), (131, 262), (262, 393)]
    for n in range(1, 900):
        bounds = cut_bounds(n, BANDAI2_CLIP_FRAMES)
        lengths = [b - a for a, b in bounds]
        assert bounds[0][0] == 0 and bounds[-1][1] == n
        assert all(bounds[i][1] == bounds[i + 1][0] for i in range(len(bounds) - 1))
        assert len(bounds) == math.ceil(n / BANDAI2_CLIP_FRAMES)
        assert max(lengths) <= BANDAI2_CLIP_FRAMES and max(lengths) - min(lengths) <= 1
        if len(bounds) > 1:
            assert min(lengths) >= BANDAI2_CLIP_FRAMES // 2
    with pytest.raises(ValueError):
        cut_bounds(10, 0)


def test_split_rule_for_bandai2_ids() -> None:
    takes = [(f"dataset-2_walk_normal_{i:03d}", ("walk", "normal")) for i in range(19, 0, -1)]
    takes += [(f"dataset-2_walk_elderly_{i:03d}", ("walk", "elderly")) for i in range(1, 18)]
    split = split_takes(takes, val_takes=3, test_takes=3)
    normal = {s: [t[-3:] for t, _ in takes if split[t] == s and "normal" in t] for s in ("train", "val", "test")}
    assert sorted(normal["train"]) == [f"{i:03d}" for i in range(1, 14)]
    assert sorted(normal["val"]) == ["014", "015", "016"] and sorted(normal["test"]) == ["017", "018", "019"]
    elderly = {s: sorted(t[-3:] for t, _ in takes if split[t] == s and "elderly" in t) for s in ("val", "test")}
    assert elderly == {"val": ["012", "013", "014"], "test": ["015", "016", "017"]}

    def few(n: int) -> list[str]:
        return sorted(split_takes([(f"t_{i}", ("a", "b")) for i in range(n)], 3, 3).values())

    assert few(1) == ["train"] and few(2) == ["test", "train"] and few(3) == ["test", "train", "val"]
    assert few(4) == ["test", "test", "train", "val"]
    assert split_takes([("x_1", ("a", "b"))], 0, 0) == {"x_1": "train"}


# ---- a synthetic Bandai-2 folder ----------------------------------------------------------------------------------

# (content index, style index) -> 30 fps frame counts of takes 001, 002, ... (walk/elderly lacks its last take,
# like the real walk/elderly); long takes get cut, short ones fall under MDM's 40 frames.
TAKES = {
    (0, 5): [450, 120, 90, 600, 150],  # walk / normal
    (0, 1): [300, 75, 45, 96],  # walk / elderly
    (8, 5): [40, 60, 66, 72, 84],  # raise-up-left-hand / normal
    (8, 1): [100, 110, 299, 70, 80],  # raise-up-left-hand / elderly
}


def synthetic_bvh(n_frames: int, drift: float) -> str:
    """The fixture's skeleton with ``n_frames`` of its motion played back and forth, the root gliding in x by
    ``drift`` cm a frame every other 20 frames (so feet both slide and stand, and takes differ in root speed)."""
    header, _, motion = TEMPLATE.read_text(encoding="utf-8").partition("MOTION")
    lines = [ln for ln in motion.strip().splitlines()[2:] if ln.strip()]
    cycle = lines + lines[-2:0:-1]
    frames, offset = [], 0.0
    for f in range(n_frames):
        offset += drift if (f // 20) % 2 else 0.0
        values = cycle[f % len(cycle)].split()
        values[0] = f"{float(values[0]) + offset:.4f}"
        frames.append(" ".join(values))
    return f"{header}MOTION\nFrames:\t{n_frames}\nFrame Time:\t0.0333333\n" + "\n".join(frames) + "\n"


def write_synthetic_dataset(root: Path) -> Path:
    dataset = root / "dataset-2"
    (dataset / "data").mkdir(parents=True)
    shutil.copytree(FIXTURES / "dataset-2" / "cfg", dataset / "cfg")
    shutil.copyfile(FIXTURES / "LICENSE", dataset / "LICENSE")
    contents, styles = CONTENTS["dataset-2"], STYLES["dataset-2"]
    for (ci, si), lengths in TAKES.items():
        for number, n_frames in enumerate(lengths, 1):
            stem = f"dataset-2_{contents[ci]}_{styles[si]}_{number:03d}"
            (dataset / "data" / f"{stem}.bvh").write_text(synthetic_bvh(n_frames, 4.0 + 0.5 * number), encoding="utf-8")
            (dataset / "data" / f"{stem}.json").write_text(json.dumps({"content": ci, "style": si}), encoding="utf-8")
    return dataset


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_synthetic_dataset(tmp_path_factory.mktemp("bandai"))


@pytest.fixture(scope="module")
def corpus(dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("corpus") / "bandai2"
    summary = import_bvh(dataset, out, max_frames=BANDAI2_CLIP_FRAMES, val_takes=1, test_takes=1, mean_std=True)
    assert summary.rejects == [] and summary.takes == 19 and summary.missing_pairs == {}
    return out


@pytest.fixture(scope="module")
def whole_takes(dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("whole") / "bandai2"
    import_bvh(dataset, out)
    return out


def ids(path: Path) -> list[str]:
    return [line for line in path.read_text(encoding="utf-8").splitlines() if line]


def motion(root: Path, clip_id: str) -> np.ndarray:
    return np.load(root / "new_joint_vecs" / f"{clip_id}.npy")


def test_long_takes_are_cut_into_equal_unpadded_pieces(corpus: Path, whole_takes: Path) -> None:
    labels = read_labels(corpus)
    pieces: dict[str, list[str]] = {}
    for clip_id in ids(corpus / "all.txt"):
        pieces.setdefault(labels[clip_id]["meta"].get("take", clip_id), []).append(clip_id)
    assert sorted(pieces) == sorted(ids(whole_takes / "all.txt"))
    n_cut = 0
    for take, members in pieces.items():
        whole = motion(whole_takes, take)
        parts = [motion(corpus, m) for m in members]
        lengths = [len(p) for p in parts]
        assert len(members) == math.ceil(len(whole) / BANDAI2_CLIP_FRAMES), take
        assert max(lengths) <= BANDAI2_CLIP_FRAMES and max(lengths) - min(lengths) <= 1, (take, lengths)
        np.testing.assert_array_equal(np.concatenate(parts), whole)  # nothing padded, dropped or reordered
        if len(members) > 1:
            n_cut += 1
            for member in members:  # each piece a clip of its own: own id, own whole-clip captions
                start, stop = (int(x) for x in labels[member]["meta"]["frames"].split("-"))
                assert member == f"{take}_{round(start * 5):04d}_{round(stop * 5):04d}"
                lines = (corpus / "texts" / f"{member}.txt").read_text(encoding="utf-8").splitlines()
                assert len(lines) == 3 and all(line.endswith("#0.0#0.0") for line in lines)
    assert n_cut == 4  # walk/normal 001, 004, walk/elderly 001, raise-up-left-hand/elderly 003


def test_too_short_clips_stay_and_are_listed(corpus: Path) -> None:
    all_ids = ids(corpus / "all.txt")
    short = [i for i in all_ids if len(motion(corpus, i)) < MDM_MIN_FRAMES]
    assert short and ids(corpus / TOO_SHORT_FILE) == short
    splits = {s: set(ids(corpus / f"{s}.txt")) for s in ("train", "val", "test")}
    assert all(any(i in members for members in splits.values()) for i in short)


def test_splits_hold_every_pair_and_whole_takes(corpus: Path) -> None:
    labels = read_labels(corpus)
    splits = {s: ids(corpus / f"{s}.txt") for s in ("train", "val", "test")}
    all_ids = ids(corpus / "all.txt")
    assert sorted(sum(splits.values(), [])) == sorted(all_ids)  # disjoint and complete
    assert ids(corpus / "train_val.txt") == splits["train"] + splits["val"]
    pairs = {(r["content"], r["style"]) for r in labels.values()}
    assert len(pairs) == 4
    split_of_take: dict[str, str] = {}
    for name, members in splits.items():
        assert {(labels[i]["content"], labels[i]["style"]) for i in members} == pairs, name
        for clip_id in members:
            assert labels[clip_id]["meta"]["split"] == name
            take = labels[clip_id]["meta"].get("take", clip_id)
            assert split_of_take.setdefault(take, name) == name, f"{take} is split across {name}"
    assert {t for t, s in split_of_take.items() if s == "test"} == {
        "dataset-2_walk_normal_005",
        "dataset-2_walk_elderly_004",
        "dataset-2_raise-up-left-hand_normal_005",
        "dataset-2_raise-up-left-hand_elderly_005",
    }


def test_mean_std_come_from_the_train_split_only(corpus: Path) -> None:
    mean, std = np.load(corpus / "Mean.npy"), np.load(corpus / "Std.npy")
    assert mean.dtype == np.float32 and mean.shape == std.shape == (263,)
    train = compute_mean_std(motion(corpus, i) for i in ids(corpus / "train.txt"))
    every = compute_mean_std(motion(corpus, i) for i in ids(corpus / "all.txt"))
    np.testing.assert_allclose(mean, train.mean, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(std, train.std, rtol=1e-6, atol=1e-6)
    assert not np.allclose(mean, every.mean, atol=1e-4)


def test_licence_is_recorded(corpus: Path, whole_takes: Path, tmp_path: Path) -> None:
    for root in (corpus, whole_takes):
        assert corpus_licence(root) == BANDAI_LICENCE
        notice = (root / "NOTICE").read_text(encoding="utf-8")
        assert "CC BY-NC 4.0" in notice and "non-commercial" in notice.lower() and "Bandai Namco Research" in notice
        assert (root / "LICENSE").read_bytes() == (FIXTURES / "LICENSE").read_bytes()
    meta = json.loads((corpus / "corpus.json").read_text(encoding="utf-8"))
    assert meta["licence"] == BANDAI_LICENCE and meta["commercial_use"] is False
    assert meta["mean_std"] == "train split" and meta["splits"]["test"] == len(ids(corpus / "test.txt"))
    assert corpus_licence(tmp_path) is None
    (tmp_path / "corpus.json").write_text("{not json", encoding="utf-8")
    with pytest.raises(MotionDataError, match="corpus.json"):
        corpus_licence(tmp_path)


def test_labels_survive_in_the_sidecar(corpus: Path) -> None:
    clips = list(HumanML3DReader(corpus, split="all"))
    assert len(clips) == len(ids(corpus / "all.txt"))
    assert {(c.content, c.style) for c in clips} == {
        ("walk", "normal"),
        ("walk", "elderly"),
        ("raise-up-left-hand", "normal"),
        ("raise-up-left-hand", "elderly"),
    }
    for clip in clips:
        assert len(clip.captions) == 3
        styled = clip.style != "normal"
        assert all(has_style_words(c, VOCAB) == styled for c in clip.captions), clip.id


def mdm_text2motion_v2(root: Path, split: str, fps: int = 20) -> dict[str, list[str]]:
    """The clips MDM's ``Text2MotionDatasetV2`` keeps from ``<split>.txt``, with their captions, by its rules:
    ids from the split file; ``new_joint_vecs/<id>.npy`` must have 40 <= T < 200 frames; each ``texts/<id>.txt``
    line is ``caption#tokens#start#end`` with space-separated ``word/POS`` tokens (its word vectorizer splits each on
    '/'); a 0/0 span is a caption of the whole clip, any other span is cut ``[int(start*20):int(end*20)]`` and kept
    as its own clip when 40 <= len < 200; a clip with no whole-clip caption is not kept. Unlike MDM, which skips any
    clip whose reading raises, this raises, so a malformed file fails the test."""
    kept: dict[str, list[str]] = {}
    for name in (root / f"{split}.txt").read_text(encoding="utf-8").splitlines():
        name = name.strip()
        clip = np.load(root / "new_joint_vecs" / f"{name}.npy")
        if not MDM_MIN_FRAMES <= len(clip) < 200:
            continue
        whole = []
        for line in (root / "texts" / f"{name}.txt").read_text(encoding="utf-8").splitlines():
            caption, tokens, start, end = line.strip().split("#")
            for token in tokens.split(" "):
                word, pos = token.split("/")
                assert word and pos
            start_s = 0.0 if math.isnan(float(start)) else float(start)
            end_s = 0.0 if math.isnan(float(end)) else float(end)
            if start_s == 0.0 and end_s == 0.0:
                whole.append(caption)
            elif MDM_MIN_FRAMES <= len(clip[int(start_s * fps) : int(end_s * fps)]) < 200:
                kept[f"{name}@{start}-{end}"] = [caption]
        if whole:
            kept[name] = whole
    return kept


def test_mdm_loader_accepts_every_clip_of_40_frames_or_more(corpus: Path) -> None:
    for split in ("train", "val", "test", "all"):
        listed = ids(corpus / f"{split}.txt")
        long_enough = {i for i in listed if len(motion(corpus, i)) >= MDM_MIN_FRAMES}
        assert all(len(motion(corpus, i)) <= BANDAI2_CLIP_FRAMES for i in listed)
        kept = mdm_text2motion_v2(corpus, split)
        assert set(kept) == long_enough, split
        assert all(len(captions) == 3 for captions in kept.values())
    assert len(mdm_text2motion_v2(corpus, "all")) == len(ids(corpus / "all.txt")) - len(ids(corpus / TOO_SHORT_FILE))


def test_parquet_import_carries_splits_and_train_stats(dataset: Path, corpus: Path, tmp_path: Path) -> None:
    out = tmp_path / "parquet"
    summary = import_bvh(
        dataset, out, "parquet", max_frames=BANDAI2_CLIP_FRAMES, val_takes=1, test_takes=1, mean_std=True
    )
    clips = {c.id: c for c in read_parquet_corpus(out)}
    assert set(clips) == set(ids(corpus / "all.txt")) and summary.splits["test"] == len(ids(corpus / "test.txt"))
    assert all(clips[i].meta["split"] == "val" for i in ids(corpus / "val.txt"))
    np.testing.assert_allclose(np.load(out / "Mean.npy"), np.load(corpus / "Mean.npy"), rtol=1e-5, atol=1e-5)
    assert corpus_licence(out / "corpus.parquet") == BANDAI_LICENCE
    assert ids(out / TOO_SHORT_FILE) == ids(corpus / TOO_SHORT_FILE)


def test_other_inputs_keep_todays_behaviour(tmp_path: Path) -> None:
    src = tmp_path / "mocap" / "my_take.bvh"
    src.parent.mkdir()
    src.write_text(synthetic_bvh(120, 0.5), encoding="utf-8")
    out = tmp_path / "out"
    summary = import_bvh(src, out, content="walk", style="proud")
    assert summary.clips == 1 and summary.licence is None and summary.splits == {}
    assert ids(out / "all.txt") == ["my_take"]
    assert not (out / "train.txt").exists() and not (out / "Mean.npy").exists() and not (out / "NOTICE").exists()
    assert corpus_licence(out) is None
    assert read_labels(out)["my_take"]["style"] == "proud"
    licensed = import_bvh(src, tmp_path / "licensed", content="walk", licence="CC BY 4.0, Example Lab")
    assert corpus_licence(tmp_path / "licensed") == "CC BY 4.0, Example Lab" == licensed.licence
    with pytest.raises(MotionDataError, match="is not empty; pass --append .* or --force"):
        import_bvh(src, out, content="walk")


def test_cli_imports_with_the_bandai2_options(dataset: Path, tmp_path: Path) -> None:
    from motionaug.workflows.cli import app

    out = tmp_path / "cli"
    args = [str(dataset), "--out", str(out), "--max-frames", "196", "--val-takes", "1", "--test-takes", "1"]
    result = CliRunner().invoke(app, ["corpus", "import-bvh", *args, "--mean-std"])
    assert result.exit_code == 0, result.output
    assert "19" in result.output and "rejected" in result.output
    assert (out / "Mean.npy").is_file() and (out / "test.txt").is_file() and corpus_licence(out) == BANDAI_LICENCE


# ---- target folder: --append, --force, all or nothing ------------------------------------------------------------


def tree(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def one_take(folder: Path, name: str, n_frames: int = 200, text: str | None = None) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.bvh"
    path.write_text(text if text is not None else synthetic_bvh(n_frames, 4.5), encoding="utf-8")
    return path


def test_append_adds_new_ids_and_never_overwrites(tmp_path: Path) -> None:
    out = tmp_path / "corpus"
    import_bvh(one_take(tmp_path / "a", "dataset-2_walk_proud_001"), out, mean_std=True)
    before = tree(out)
    batch = tmp_path / "b"
    one_take(batch, "dataset-2_walk_proud_001", 150)  # same id, different motion: must be skipped
    one_take(batch, "dataset-2_walk_proud_002")
    summary = import_bvh(batch, out, mode="append", mean_std=True)
    assert summary.clips == 1 and summary.skipped == ["dataset-2_walk_proud_001"]
    after = tree(out)
    assert after["new_joint_vecs/dataset-2_walk_proud_001.npy"] == before["new_joint_vecs/dataset-2_walk_proud_001.npy"]
    assert ids(out / "all.txt") == ["dataset-2_walk_proud_001", "dataset-2_walk_proud_002"]
    assert set(read_labels(out)) == {"dataset-2_walk_proud_001", "dataset-2_walk_proud_002"}
    assert json.loads((out / "corpus.json").read_text())["clips"] == 2
    assert len(list(HumanML3DReader(out, on_error="raise"))) == 2
    expected = compute_mean_std(motion(out, i) for i in ids(out / "all.txt"))
    np.testing.assert_allclose(np.load(out / "Mean.npy"), expected.mean, rtol=1e-5, atol=1e-6)
    assert not list(tmp_path.glob(".*.tmp"))


def test_parquet_append_adds_a_file(tmp_path: Path) -> None:
    out = tmp_path / "pq"
    import_bvh(one_take(tmp_path / "a", "dataset-2_walk_proud_001"), out, "parquet")
    summary = import_bvh(one_take(tmp_path / "b", "dataset-2_walk_proud_002"), out, "parquet", mode="append")
    assert summary.clips == 1
    assert sorted(c.id for c in read_parquet_corpus(out)) == ["dataset-2_walk_proud_001", "dataset-2_walk_proud_002"]
    with pytest.raises(MotionDataError, match="holds a parquet corpus; --append needs --format parquet"):
        import_bvh(tmp_path / "b", out, mode="append")


def test_force_replaces_and_a_failed_import_changes_nothing(tmp_path: Path) -> None:
    out = tmp_path / "corpus"
    import_bvh(one_take(tmp_path / "a", "dataset-2_walk_proud_001"), out)
    before = tree(out)
    broken = one_take(tmp_path / "bad", "dataset-2_walk_proud_009", text="HIERARCHY\nROOT nothing\n")
    for mode in ("force", "append"):
        with pytest.raises(MotionDataError, match=r"nothing imported \(1 rejected, 0 already in"):
            import_bvh(broken, out, mode=mode)
        assert tree(out) == before, mode
    with pytest.raises(MotionDataError, match=r"nothing imported \(0 rejected, 1 already in"):
        import_bvh(tmp_path / "a", out, mode="append")
    summary = import_bvh(one_take(tmp_path / "c", "dataset-2_dash_old_003"), out, mode="force")
    assert summary.clips == 1 and ids(out / "all.txt") == ["dataset-2_dash_old_003"]
    assert set(tree(out)) == {k for k in before if "walk_proud_001" not in k} | {
        "new_joint_vecs/dataset-2_dash_old_003.npy",
        "texts/dataset-2_dash_old_003.txt",
    }
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep")
    with pytest.raises(MotionDataError, match="holds no corpus, so --force will not touch it"):
        import_bvh(tmp_path / "c", tmp_path / "mine", mode="force")
    assert (tmp_path / "mine" / "notes.txt").read_text() == "keep"


def test_rejects_name_the_option_that_fixes_them(tmp_path: Path) -> None:
    renamed = TEMPLATE.read_text(encoding="utf-8").replace("Hips", "Pelvis")
    src = tmp_path / "mocap"
    one_take(src, "take_one")
    one_take(src, "dataset-2_walk_proud_002", text=renamed)
    with pytest.raises(MotionDataError, match="nothing imported") as err:
        import_bvh(src, tmp_path / "out")
    assert "--joint-map" in err.value.reason  # the first reject (sorted file order) with its fix
    rejects: list = []
    assert list(iter_bvh_clips(src, rejects)) == []
    reasons = {r.id: r.reason for r in rejects}
    assert "--content" in reasons["take_one"] and "--joint-map" in reasons["dataset-2_walk_proud_002"]
    assert "docs/joint-map.md" in reasons["dataset-2_walk_proud_002"]


def test_style_alone_relabels_bandai_files(tmp_path: Path) -> None:
    out = tmp_path / "out"
    import_bvh(one_take(tmp_path / "a", "dataset-2_walk_proud_001"), out, style="elderly")
    assert read_labels(out)["dataset-2_walk_proud_001"]["content"] == "walk"
    assert read_labels(out)["dataset-2_walk_proud_001"]["style"] == "elderly"


MIXAMO_NAMES = {"Chest": "Spine2", "Shoulder_": "Shoulder", "UpperArm_": "Arm", "LowerArm_": "ForeArm"}


def mixamo_rig(text: str) -> str:
    """The Bandai fixture's skeleton under the Mixamo-style names of docs/examples/joint-map.json."""
    for side, word in (("L", "Left"), ("R", "Right")):
        for bandai, mixamo in (
            ("Shoulder", "Shoulder"),
            ("UpperArm", "Arm"),
            ("LowerArm", "ForeArm"),
            ("Hand", "Hand"),
            ("UpperLeg", "UpLeg"),
            ("LowerLeg", "Leg"),
            ("Foot", "Foot"),
            ("Toes", "ToeBase"),
        ):
            text = re.sub(rf"\b{bandai}_{side}\b", f"{word}{mixamo}", text)
    return re.sub(r"\bChest\b", "Spine2", text)


def test_example_joint_map_imports_a_renamed_rig(tmp_path: Path) -> None:
    example = Path(__file__).resolve().parents[1] / "docs" / "examples" / "joint-map.json"
    assert JointMap.from_file(example).name == "mixamo-style-example"
    one_take(tmp_path / "bandai", "dataset-2_walk_proud_001", text=synthetic_bvh(60, 1.0))
    one_take(tmp_path / "mixamo", "dataset-2_walk_proud_001", text=mixamo_rig(synthetic_bvh(60, 1.0)))
    import_bvh(tmp_path / "bandai", tmp_path / "ref")
    with pytest.raises(MotionDataError, match="--joint-map"):
        import_bvh(tmp_path / "mixamo", tmp_path / "unmapped")
    import_bvh(tmp_path / "mixamo", tmp_path / "mapped", joint_map=example)
    clip = "dataset-2_walk_proud_001"
    assert np.array_equal(motion(tmp_path / "mapped", clip), motion(tmp_path / "ref", clip))
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({**json.loads(example.read_text()), "scale": -1}))
    with pytest.raises(MotionDataError, match=r"bad joint map: scale: .*docs/joint-map.md") as err:
        import_bvh(tmp_path / "mixamo", tmp_path / "never", joint_map=bad)
    assert err.value.source == str(bad) and not (tmp_path / "never").exists()


def test_cli_refuses_a_full_folder_and_fails_when_nothing_is_imported(tmp_path: Path) -> None:
    from motionaug.workflows.cli import app

    out = tmp_path / "out"
    take = one_take(tmp_path / "a", "dataset-2_walk_proud_001")
    assert CliRunner().invoke(app, ["corpus", "import-bvh", str(take), "--out", str(out)]).exit_code == 0
    again = CliRunner().invoke(app, ["corpus", "import-bvh", str(take), "--out", str(out)])
    assert again.exit_code == 1 and "--append" in again.output and "--force" in again.output
    both = CliRunner().invoke(app, ["corpus", "import-bvh", str(take), "--out", str(out), "--append", "--force"])
    assert both.exit_code == 2
    skipped = CliRunner().invoke(app, ["corpus", "import-bvh", str(take), "--out", str(out), "--append"])
    assert skipped.exit_code == 1 and "nothing imported (0 rejected, 1 already in" in skipped.output


# ---- the real Bandai-2 ----------------------------------------------------------------------------------------------


def test_real_bandai2_pair_imports_training_ready(tmp_path: Path) -> None:
    """walk/elderly, the pair with 17 takes (not 19) and the longest walks: cut, split 11/3/3, accepted by MDM."""
    data = require_shared_data("bandai", "dataset-2")
    src = tmp_path / "dataset-2"
    (src / "data").mkdir(parents=True)
    shutil.copytree(data / "cfg", src / "cfg")
    for path in sorted((data / "data").glob("dataset-2_walk_elderly_*")):
        shutil.copyfile(path, src / "data" / path.name)
    out = tmp_path / "out"
    summary = import_bvh(src, out, max_frames=BANDAI2_CLIP_FRAMES, val_takes=3, test_takes=3, mean_std=True)
    assert summary.takes == 17 and summary.rejects == [] and summary.cut_takes > 0
    labels = read_labels(out)
    takes = {s: sorted({labels[i]["meta"].get("take", i)[-3:] for i in ids(out / f"{s}.txt")}) for s in ("val", "test")}
    assert takes == {"val": ["012", "013", "014"], "test": ["015", "016", "017"]}
    assert all(len(motion(out, i)) <= BANDAI2_CLIP_FRAMES for i in ids(out / "all.txt"))
    assert set(mdm_text2motion_v2(out, "train")) == {
        i for i in ids(out / "train.txt") if len(motion(out, i)) >= MDM_MIN_FRAMES
    }
    assert corpus_licence(out) == BANDAI_LICENCE


# ---- training-ready by default, labels from file names ----------------------------------------------------------


def test_cli_with_no_flags_writes_what_the_bandai2_protocol_writes(dataset: Path, corpus: Path, tmp_path: Path) -> None:
    """Pairs of 4-5 takes: 15% rounds to one val and one test take each, as the ``corpus`` fixture's explicit flags."""
    from motionaug.workflows.cli import app

    out = tmp_path / "plain"
    result = CliRunner().invoke(app, ["corpus", "import-bvh", str(dataset), "--out", str(out)])
    assert result.exit_code == 0, result.output
    for name in ("all.txt", "train.txt", "val.txt", "test.txt", "train_val.txt"):
        assert ids(out / name) == ids(corpus / name), name
    assert (out / "Mean.npy").read_bytes() == (corpus / "Mean.npy").read_bytes()
    assert max(len(np.load(f)) for f in (out / "new_joint_vecs").glob("*.npy")) <= BANDAI2_CLIP_FRAMES
    assert all(mdm_text2motion_v2(out, split) for split in ("train", "val", "test"))
    assert json.loads((out / "corpus.json").read_text(encoding="utf-8"))["split_rule"].startswith("per (content")


def test_auto_takes_scale_with_the_pair_and_need_take_ids() -> None:
    assert [auto_takes(n) for n in (1, 4, 7, 10, 19, 40)] == [1, 1, 1, 2, 3, 6]
    pairs = [(f"t_{k:02d}", ("walk", "old")) for k in range(1, 20)]
    split = split_takes(pairs, None, None)
    assert [split[f"t_{k:02d}"] for k in range(13, 20)] == ["train"] + ["val"] * 3 + ["test"] * 3
    assert sum(v == "train" for v in split.values()) == 13


def write_style_set(root: Path) -> Path:
    """``{style}_{take}_{part}.bvh``: two styles, three takes each, two parts per take (a copy of the fixture)."""
    root.mkdir(parents=True)
    for style in ("angry", "happy"):
        for take in (1, 2, 3):
            for part in ("a", "b"):
                bvh = synthetic_bvh(60 + take, 0.0 if part == "a" else 4.0)  # standing and walking: feet vary
                (root / f"{style}_{take:02d}_{part}.bvh").write_text(bvh, encoding="utf-8")
    return root


def test_labels_from_reads_styles_and_takes_from_names_and_splits_by_take(tmp_path: Path) -> None:
    from motionaug.workflows.cli import app

    src, out = write_style_set(tmp_path / "set"), tmp_path / "c"
    args = ["corpus", "import-bvh", str(src), "--out", str(out), "--labels-from", "{style}_{take}_{part}.bvh"]
    result = CliRunner().invoke(app, [*args, "--content", "walk"])
    assert result.exit_code == 0, result.output
    labels = read_labels(out)
    assert {k: v["style"] for k, v in labels.items()} == {
        f"{s}_{t:02d}_{p}": s for s in ("angry", "happy") for t in (1, 2, 3) for p in "ab"
    }
    # three takes a pair: take 3 test, take 2 val, take 1 train; both parts of a take in one split
    for split, take in (("train", 1), ("val", 2), ("test", 3)):
        assert ids(out / f"{split}.txt") == [f"{s}_{take:02d}_{p}" for s in ("angry", "happy") for p in "ab"]
    assert (out / "Mean.npy").is_file()
    unlabelled = CliRunner().invoke(app, [*args[:4], str(tmp_path / "n"), *args[5:]])
    assert unlabelled.exit_code == 1 and "has no {content}; pass --content" in unlabelled.output


def test_a_name_that_does_not_fit_the_pattern_is_a_reject_and_fields_are_checked(tmp_path: Path) -> None:
    src = write_style_set(tmp_path / "set")
    (src / "stray.bvh").write_text(synthetic_bvh(60, 1.0), encoding="utf-8")
    summary = import_bvh(src, tmp_path / "c", content="walk", labels_from="{style}_{take}_{part}.bvh")
    assert [r.id for r in summary.rejects] == ["stray"]
    assert "does not match --labels-from" in summary.rejects[0].reason
    with pytest.raises(MotionDataError, match="has no"):
        import_bvh(src, tmp_path / "d", content="walk", labels_from="plain.bvh")
