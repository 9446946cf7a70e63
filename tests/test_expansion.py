"""The expansion protocol's pieces on a tiny synthetic corpus: split by style, merged corpora, trainings, scoring."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from motionaug.augment.eval.expansion import (
    BASE_DIR,
    HELD_OUT_DIR,
    Judge,
    StyleSplit,
    gain_share,
    judge_clips,
    mean_figures,
    merge_clips,
    score_prior,
    split_by_style,
    style_pattern,
    true_stylized,
)
from motionaug.augment.synth import STYLE_WORDS, generate_corpus
from motionaug.augment.training.data import read_clips, split_ids
from motionaug.augment.training.pretrain import PretrainConfig, for_corpus, pretrain
from motionaug.models.text_encoder import make_text_encoder
from motionaug.schemas.errors import MotionDataError
from motionaug.workflows.cli import app

STYLES = ["neutral", "proud", "angry", "old"]
CONTENTS = ["walk", "kick"]
MISSING = ["angry", "old"]


def tiny(**overrides: object) -> PretrainConfig:
    settings = {
        "prior_steps": 30,
        "encoder_steps": 10,
        "classifier_epochs": 2,
        "threads": 1,
        "log_every": 1,
        "bf16": False,
        "max_frames": 60,
        "checkpoint_every": 100,
    }
    return PretrainConfig.for_size("tiny", **{**settings, **overrides})


@pytest.fixture(scope="module")
def text_encoder():
    return make_text_encoder("minilm")


@pytest.fixture(scope="module")
def split(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("expansion")
    generate_corpus(root / "full", 90, seed=3, styles=STYLES, contents=CONTENTS, neutral_fraction=0.4)
    split_by_style(root / "full", root / "split", MISSING, n_expand=6, seed=0)
    return root / "split"


def test_base_lacks_the_missing_styles_in_motions_and_captions(split: Path) -> None:
    info = StyleSplit.read(split)
    base = split / BASE_DIR
    clips = read_clips(base, split_ids(base, "all"))
    assert {c.style for c in clips} == {"neutral", "proud"}
    named = style_pattern(MISSING, STYLE_WORDS)
    assert not [cap.text for c in clips for cap in c.captions if named.search(cap.text)]
    assert named.search("a person kicks angrily") and named.search("a man walks like an old person")
    # the held-out set is the corpus's test split, every style; the base trains on none of it
    held = split_ids(split / HELD_OUT_DIR, "test")
    assert not set(held) & set(split_ids(base, "train") + split_ids(base, "val"))
    assert info.held_out["style_prompted"] > 0 and sum(info.held_out.values()) == len(held)
    # one example per missing style, from the train split and outside the base
    assert set(info.examples) == set(MISSING)
    for style, example in info.examples.items():
        assert example["id"] not in {c.id for c in clips}
        assert read_clips(info.corpus, [example["id"]])[0].style == style
        assert np.load(split / example["path"]).shape[1] == 263
    assert len(info.expand_ids) == 6 and set(info.expand_ids) <= set(split_ids(base, "train"))


def test_halves_keep_the_judges_takes_out_of_c_and_the_examples(split: Path, tmp_path: Path) -> None:
    corpus = Path(StyleSplit.read(split).corpus)
    info = split_by_style(corpus, tmp_path / "halves", MISSING, n_expand=6, seed=0, halves=True)
    judge = {c.id for c in judge_clips(tmp_path / "halves")}
    truth = {c.id for c in true_stylized(tmp_path / "halves", mode="corpus")}
    missing_train = {c.id for c in read_clips(corpus, split_ids(corpus, "train")) if c.style in MISSING}
    assert judge == set(info.judge_ids) and judge and truth and not judge & truth
    assert judge | truth == missing_train and len(judge) <= len(truth)  # C's half takes each first take
    assert not {e["id"] for e in info.examples.values()} & judge
    # without halves nothing is set aside and C holds every train clip of the missing styles
    assert {c.id for c in true_stylized(split, mode="corpus")} == missing_train


def test_split_refuses_unknown_or_neutral_styles(split: Path, tmp_path: Path) -> None:
    corpus = Path(StyleSplit.read(split).corpus)
    for missing in (["sneaky"], ["neutral"], []):
        with pytest.raises(MotionDataError, match="missing styles"):
            split_by_style(corpus, tmp_path / "x", missing)


def test_three_trainings_lower_their_loss_and_are_scored(split: Path, text_encoder, tmp_path: Path) -> None:
    info = StyleSplit.read(split)
    truth = list(true_stylized(split))
    assert {(c.meta["source_id"], c.style) for c in truth} == {(i, s) for i in info.expand_ids for s in MISSING}
    base = split / BASE_DIR
    sizes = {
        "A": None,
        "B": merge_clips(base, truth[: len(truth) // 2], tmp_path / "B"),  # stands in for a run's export
        "C": merge_clips(base, truth, tmp_path / "C"),
    }
    assert sizes["C"]["train"] == info.base_splits["train"] + len(truth)
    assert sizes["C"]["test"] == info.base_splits["test"]
    assert split_ids(tmp_path / "C", "added") == [c.id for c in truth]
    with pytest.raises(MotionDataError, match="not empty"):
        merge_clips(base, truth, tmp_path / "C")
    shared = tiny(added_share=0.5)  # B and C draw half their clips from the added ones; A has none to weigh
    hashes = [for_corpus(shared, corpus).config_hash() for corpus in (base, tmp_path / "C")]
    assert hashes[0] == tiny().config_hash() != hashes[1]
    for name in ("A", "B", "C"):
        corpus = base if name == "A" else tmp_path / name
        pretrain(corpus, tmp_path / f"prior_{name}", shared, text_encoder=text_encoder)
        losses = [
            json.loads(line)["loss"]
            for line in (tmp_path / f"prior_{name}" / "loss_log.jsonl").read_text().splitlines()
            if json.loads(line)["stage"] == "prior" and "loss" in json.loads(line)
        ]
        assert np.mean(losses[-5:]) < np.mean(losses[:5]), name
    pretrain(Path(info.corpus), tmp_path / "judge", tiny(seed=1), text_encoder=text_encoder)
    judge = Judge(tmp_path / "judge")
    figures = score_prior(tmp_path / "prior_C", split / HELD_OUT_DIR, judge, MISSING, steps=4, batch_size=16)
    assert figures["all"]["samples"] == 3 * sum(info.held_out.values())
    assert figures["style_prompted"]["samples"] == 3 * info.held_out["style_prompted"]
    for group in figures.values():
        assert 0.0 <= group["content"] <= 1.0 and 0.0 <= group["style"] <= 1.0
        assert group["diversity"] is None or group["diversity"] > 0
    assert figures["all"]["fmd"] is not None and figures["all"]["fmd"] >= 0
    twice = score_prior(
        tmp_path / "prior_C",
        split / HELD_OUT_DIR,
        judge,
        MISSING,
        steps=4,
        batch_size=16,
        samples=2,
        groups=["neutral"],
    )
    assert list(twice) == ["neutral"] and twice["neutral"]["samples"] == 2 * figures["neutral"]["samples"]


def test_gain_share() -> None:
    assert gain_share(0.1, 0.6, 0.8) == pytest.approx(0.5 / 0.7)
    assert gain_share(0.5, 0.6, 0.5) is None and gain_share(None, 0.6, 0.8) is None


def test_mean_figures_averages_seeds_key_by_key() -> None:
    runs = [
        {"neutral": {"content": 0.8, "fmd": 10.0, "n": 90}, "all": {"fmd": None}, "label": "x"},
        {"neutral": {"content": 0.6, "fmd": 30.0, "n": 90}, "all": {"fmd": 2.0}, "label": "x"},
    ]
    mean = mean_figures(runs)
    assert mean["neutral"] == {"content": pytest.approx(0.7), "fmd": pytest.approx(20.0), "n": 90.0}
    assert mean["all"]["fmd"] is None and mean["label"] == "x"
    assert mean_figures(runs[:1])["neutral"]["content"] == pytest.approx(0.8)


def test_commands_split_and_truth(split: Path, tmp_path: Path) -> None:
    corpus = StyleSplit.read(split).corpus
    runner = CliRunner()
    made = runner.invoke(app, ["expansion", "split", corpus, "--out", str(tmp_path / "s"), "--missing", "old"])
    assert made.exit_code == 0, made.output
    assert StyleSplit.read(tmp_path / "s").missing == ["old"]
    truth = runner.invoke(app, ["expansion", "truth", str(tmp_path / "s"), "--out", str(tmp_path / "c")])
    assert truth.exit_code == 0, truth.output
    clips = read_clips(tmp_path / "c", split_ids(tmp_path / "c", "train"))
    assert "old" in {c.style for c in clips} and "angry" in {c.style for c in clips}  # angry stays in this A
    bad = runner.invoke(app, ["expansion", "split", corpus, "--out", str(tmp_path / "t"), "--missing", "sneaky"])
    assert bad.exit_code == 1 and "missing styles" in bad.output and len(bad.output.strip().splitlines()) == 1
    no_half = runner.invoke(app, ["expansion", "judge-corpus", str(tmp_path / "s"), "--out", str(tmp_path / "j")])
    assert no_half.exit_code == 1 and "--halves" in no_half.output and len(no_half.output.strip().splitlines()) == 1
    cmd = ["expansion", "split", corpus, "--out", str(tmp_path / "h"), "--missing", "old", "--halves"]
    assert runner.invoke(app, cmd).exit_code == 0
    judged = runner.invoke(app, ["expansion", "judge-corpus", str(tmp_path / "h"), "--out", str(tmp_path / "j")])
    assert judged.exit_code == 0, judged.output
    judge_train = {c.id for c in read_clips(tmp_path / "j", split_ids(tmp_path / "j", "train")) if c.style == "old"}
    assert judge_train == set(StyleSplit.read(tmp_path / "h").judge_ids)
