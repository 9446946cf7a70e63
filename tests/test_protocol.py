"""The held-out protocol: what a method may see (train views, example draws, blinded clips, style folds)."""

from __future__ import annotations

import copy
import json
import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from conftest import TWO_STYLES

from motionaug.augment.corpus import Corpus
from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.corpus.style_sets import with_counterparts, without_styles, write_without_styles
from motionaug.augment.eval.protocol import (
    LSO_FOLDS,
    ExampleDraws,
    ProtocolLeak,
    TrainView,
    blind,
    check_held_out,
    draw_examples,
    guarded,
    held_out_leaks,
    scored_overlap,
    take_of,
)
from motionaug.augment.methods.registry import known_methods, method_class
from motionaug.augment.outputs.run_dir import RunDir
from motionaug.augment.outputs.shards import row_motion
from motionaug.augment.synth import generate_corpus
from motionaug.schemas.run_config import load_run_config


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("protocol") / "corpus"
    generate_corpus(root, 60, seed=0)
    return root


def split_ids(corpus: Path, split: str) -> list[str]:
    return (corpus / f"{split}.txt").read_text(encoding="utf-8").split()


def test_pieces_of_a_cut_take_share_the_take() -> None:
    assert take_of("dataset-2_walk_elderly_004_0000_0196") == "dataset-2_walk_elderly_004"
    assert take_of("dataset-2_walk_elderly_004_0196_0392") == "dataset-2_walk_elderly_004"
    assert take_of("000123") == "000123"


def test_counterparts_follow_the_written_table() -> None:
    assert with_counterparts(["elderly"]) == {"old", "elderly"}
    assert with_counterparts(["youthful"]) == {"childish", "youthful", "childlike"}
    assert with_counterparts(["sneaky"]) == {"sneaky"}  # no counterpart: only itself
    for fold in LSO_FOLDS["bandai2"]:
        assert set(fold.held_out) <= fold.removed()
    clips = [MotionClip(id=s, motion=np.zeros((2, 263), np.float32), captions=[], style=s) for s in ("old", "proud")]
    assert [c.id for c in without_styles(clips, ["elderly"])] == ["proud"]


def test_a_filtered_corpus_lacks_the_styles_and_renormalises(corpus: Path, tmp_path: Path) -> None:
    out = write_without_styles(corpus, tmp_path / "minus-old", ["elderly"])  # synthetic 'old' is its counterpart
    kept = list(Corpus(out))
    assert kept and all(c.style != "old" for c in kept)
    assert len(kept) == sum(c.style != "old" for c in Corpus(corpus))
    assert set(split_ids(out, "train")) == {c.id for c in kept} & set(split_ids(corpus, "train"))
    train = np.concatenate([c.motion for c in Corpus(out, split="train")])
    np.testing.assert_allclose(np.load(out / "Mean.npy"), train.mean(axis=0), rtol=1e-4, atol=1e-4)
    assert not np.allclose(np.load(out / "Mean.npy"), np.load(corpus / "Mean.npy"))


def test_the_train_view_refuses_every_scored_take(corpus: Path) -> None:
    scored = split_ids(corpus, "test")
    view = TrainView(corpus, scored)
    assert set(view.ids()) == set(split_ids(corpus, "train"))
    with pytest.raises(ProtocolLeak, match="scored take"):
        view.get(scored[0])
    with pytest.raises(ProtocolLeak, match="holds scored takes"):
        TrainView(corpus, scored + [split_ids(corpus, "train")[0]])
    assert guarded(list(view), scored)
    with pytest.raises(ProtocolLeak, match="pool"):
        guarded([*view, Corpus(corpus).get(scored[0])], scored)
    assert scored_overlap(view.ids(), scored) == []
    assert scored_overlap(view.ids() + scored[:2], scored) == sorted(scored[:2])


def test_example_draws_are_fixed_disjoint_and_prefer_walks(corpus: Path, tmp_path: Path) -> None:
    view = TrainView(corpus, split_ids(corpus, "test"))
    styles = ["proud", "old"]
    draws = draw_examples(view, styles, k=1, n_draws=2, seed=0)
    assert draws == draw_examples(view, styles, k=1, n_draws=2, seed=0)
    assert draws != draw_examples(view, styles, k=1, n_draws=2, seed=1)
    for style in styles:
        ids = [i for draw in draws.draws[style] for i in draw]
        assert len({take_of(i) for i in ids}) == len(ids)  # disjoint across draws
        assert all(view.get(i).style == style for i in ids)
        walks = [c for c in view if c.style == style and c.content == "walk"]
        assert (view.get(ids[0]).content == "walk") == bool(walks)
    path = draws.write(tmp_path / "draws.json")
    assert ExampleDraws.model_validate(json.loads(path.read_text())) == draws
    with pytest.raises(Exception, match="needed for the draws"):
        draw_examples(view, ["proud"], k=50, n_draws=3)


def test_blinded_clips_carry_motion_and_captions_only(corpus: Path) -> None:
    clips = list(Corpus(corpus, split="test"))[:3]
    for before, after in zip(clips, blind(clips)):
        assert after.content is None and after.style is None and not after.meta
        assert after.captions == before.captions and after.motion is before.motion
    assert clips[0].style is not None  # the originals keep their labels for scoring


# ---- every method, blind to the scored clips' labels --------------------------------------------------------


def with_permuted_labels(corpus: Path, out: Path, scored: list[str]) -> Path:
    """A copy of ``corpus`` whose scored clips' content and style labels are rotated among them (captions kept)."""
    shutil.copytree(corpus, out)
    rows = [json.loads(line) for line in (out / "labels.jsonl").read_text(encoding="utf-8").splitlines()]
    by_id = {r["id"]: r for r in rows}
    labels = [(by_id[i].get("content"), by_id[i].get("style")) for i in scored]
    for i, (content, style) in zip(scored, labels[1:] + labels[:1]):
        by_id[i]["content"], by_id[i]["style"] = content, style
    (out / "labels.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows), encoding="utf-8")
    return out


def protocol_config(name: str, corpus: Path, trained_on: Path, out: Path, trained: Path, examples: ExampleDraws):
    styles = []
    for style in copy.deepcopy(TWO_STYLES):
        style["examples"] = [
            {"source": i, "description": f"a person walks {style['name']}"} for i in examples.draws[style["name"]][0]
        ]
        styles.append(style)
    data = {
        "corpus": {"path": str(corpus), "split": "test", "pool_split": "train", "filters": {"min_frames": 40}},
        "styles": styles,
        "method": {"name": name, "params": dict(method_class(name).smoke_params)},
        "base_models": {"size": "tiny", "path": str(trained), "corpus": str(trained_on)},
        "compute": {"num_cpus": 1, "batch_size": 4, "unit_size": 4},
        "output": str(out),
        "seed": 0,
    }
    return load_run_config(None, data=data)


def transferred(run: Path) -> dict[tuple[str, str], tuple[bytes, object]]:
    table = pq.read_table(RunDir(run).shards_dir).to_pylist()
    return {(r["style"], r["source_id"]): (row_motion(r).tobytes(), r["captions"]) for r in table}


@pytest.mark.parametrize("name", known_methods())
def test_scored_labels_never_reach_a_method(name: str, corpus: Path, tmp_path: Path) -> None:
    """Rotating the scored clips' content and style labels changes no output bit (captions are kept). The trained
    parts never saw ``old`` (learnt from its example: Style-ERD fits a branch), as in the LSO benchmark."""
    from motionaug.workflows.executor import LocalBackend, run_pipeline
    from motionaug.workflows.pipeline import write_resolved_config

    scored = split_ids(corpus, "test")
    permuted = with_permuted_labels(corpus, tmp_path / "permuted-corpus", scored)
    assert [c.content for c in Corpus(permuted, split="test")] != [c.content for c in Corpus(corpus, split="test")]
    examples = draw_examples(TrainView(corpus, scored), ["proud", "old"], k=1, n_draws=1)
    trained_on = write_without_styles(corpus, tmp_path / "without-old", ["old"])
    outputs = []
    for label, source in (("plain", corpus), ("permuted", permuted)):
        config = protocol_config(name, source, trained_on, tmp_path / f"run-{label}", tmp_path / "trained", examples)
        check_held_out(config)
        config.output.mkdir(parents=True)
        write_resolved_config(config)
        run_pipeline(config, LocalBackend())
        outputs.append(transferred(config.output))
        if name == "erd":  # the unseen style went through the branch fit
            assert list((config.output / "styles" / "old").rglob("branch.safetensors"))
    assert outputs[0] and outputs[0].keys() == outputs[1].keys()
    assert outputs[0] == outputs[1]


def test_a_leaking_run_is_refused_before_it_starts(corpus: Path, tmp_path: Path) -> None:
    """The canary: each way a scored clip could reach a method trips the protocol's check."""
    scored = split_ids(corpus, "test")
    examples = draw_examples(TrainView(corpus, scored), ["proud", "old"], k=1, n_draws=1)
    config = protocol_config("stats", corpus, corpus, tmp_path / "run", tmp_path / "trained", examples)
    assert held_out_leaks(config) == []
    leaky_pool = config.model_copy(update={"corpus": config.corpus.model_copy(update={"pool_split": "test"})})
    with pytest.raises(ProtocolLeak, match="pool split 'test' holds"):
        check_held_out(leaky_pool)
    own_pool = config.model_copy(update={"corpus": config.corpus.model_copy(update={"pool_split": None})})
    with pytest.raises(ProtocolLeak, match="pool is the scored clips"):
        check_held_out(own_pool)
    scored_example = copy.deepcopy(examples)
    scored_example.draws["proud"][0] = [scored[0]]
    leaky_example = protocol_config("stats", corpus, corpus, tmp_path / "run", tmp_path / "trained", scored_example)
    with pytest.raises(ProtocolLeak, match="style examples are scored takes"):
        check_held_out(leaky_example)
    styles = [
        s.model_copy(update={"examples": [s.examples[0].model_copy(update={"reference": scored[1]})]})
        for s in config.styles
    ]
    with pytest.raises(ProtocolLeak, match=f"named references are scored takes \\({scored[1]}"):
        check_held_out(config.model_copy(update={"styles": styles}))
    on_all = config.model_copy(update={"corpus": config.corpus.model_copy(update={"split": "all"})})
    assert any("train split" in r for r in held_out_leaks(on_all))


def test_drop_styles_command_writes_the_fold_corpus(corpus: Path, tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from motionaug.workflows.cli import app

    result = CliRunner().invoke(
        app, ["corpus", "drop-styles", str(corpus), "--style", "elderly", "--out", str(tmp_path / "f")]
    )
    assert result.exit_code == 0, result.output
    assert "without the styles elderly, old" in " ".join(result.output.split())
    assert {c.style for c in Corpus(tmp_path / "f")} == {c.style for c in Corpus(corpus)} - {"old"}
