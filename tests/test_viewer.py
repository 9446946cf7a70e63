"""The 3D viewer's files, read without a browser: the chunks decode to the joints of the shards and the corpus
(within 1 mm), contacts follow the HumanML3D rule, the index points at the right chunks, subsets and the limb
agreement behave, and the commands write what they say. A tiny ``stats`` run on real Parquet shards."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from fixtures.evaluation.tiny_run import build_run, make_corpus
from typer.testing import CliRunner

from motionaug.augment.corpus import Corpus
from motionaug.augment.metrics import foot_contacts_from_joints
from motionaug.augment.motion.features import features_to_joints
from motionaug.augment.outputs.shards import iter_shard_rows, row_motion
from motionaug.augment.render.viewer import (
    ViewerEntry,
    choose,
    decode_joints,
    encode_joints,
    limb_agreement,
    limb_tracks,
    write_corpus_viewer,
    write_run_viewer,
)
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import T2M
from motionaug.workflows.cli import app

CALL = re.compile(r"^(motionaugIndex|motionaugChunk)\((?:(\d+), )?(.*)\);\n$", re.S)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("viewer")
    corpus = make_corpus(root / "corpus", n_clips=10)
    config = build_run(corpus, root / "run", unit_size=4)
    return {"corpus": corpus, "run": config.output}


def read_script(path: Path) -> tuple[int | None, dict]:
    """The argument of a data script: ``motionaugIndex({...});`` or ``motionaugChunk(n, {...});``."""
    match = CALL.match(path.read_text(encoding="utf-8"))
    assert match, f"{path} is not a data script"
    return (int(match[2]) if match[2] else None), json.loads(match[3])


def read_viewer(folder: Path) -> tuple[dict, dict[str, tuple[int, dict]]]:
    _, index = read_script(folder / "viewer" / "index.js")
    records: dict[str, tuple[int, dict]] = {}
    for file in sorted((folder / "viewer" / "chunks").glob("c*.js")):
        number, chunk = read_script(file)
        assert file.name == f"c{number:05d}.js"
        records.update((key, (number, record)) for key, record in chunk.items())
    return index, records


def test_encoding_round_trips_within_half_a_millimetre() -> None:
    rng = np.random.default_rng(0)
    joints = rng.normal(size=(30, 22, 3)) + np.array([40.0, 0.9, -25.0])  # far from the origin: root is float32
    back = decode_joints(encode_joints(joints), 22)
    assert np.abs(back - joints).max() <= 0.0005 + 1e-5


def test_run_viewer_holds_every_transfer_with_its_source_joints_and_contacts(tiny) -> None:
    summary = write_run_viewer(tiny["run"])
    index, records = read_viewer(tiny["run"])
    rows = list(iter_shard_rows(tiny["run"]))
    assert summary.page == tiny["run"] / "viewer.html" and summary.page.is_file()
    assert sorted(index["clips"]["id"]) == sorted(r["output_id"] for r in rows)
    assert index["default_sort"] == "limb_agreement"
    for row in rows:
        i = index["clips"]["id"].index(row["output_id"])
        chunk, record = records[row["output_id"]]
        assert chunk == index["clips"]["chunk"][i]
        expected = features_to_joints(row_motion(row))
        assert np.abs(decode_joints(record, 22) - expected).max() < 0.001
        contacts = foot_contacts_from_joints(expected, T2M)
        digits = [int(d, 16) for d in record["contacts"]]
        assert len(digits) == len(expected)
        assert digits[:-1] == [int(sum(b << k for k, b in enumerate(frame))) for frame in contacts]
        assert record["captions"] == [c["text"] for c in row["captions"]]
        assert record["before"] == [c["text"] for c in row["original_captions"]]
        assert index["source_chunks"][row["source_id"]] == records[f"src:{row['source_id']}"][0]
    for clip in Corpus(tiny["corpus"]):
        _, record = records[f"src:{clip.id}"]
        assert np.abs(decode_joints(record, 22) - features_to_joints(clip.motion)).max() < 0.001
    assert summary.bytes == sum(f.stat().st_size for f in (tiny["run"] / "viewer").rglob("*") if f.is_file())


def test_worst_subset_is_the_lowest_limb_agreement_and_ids_take_sources_or_outputs() -> None:
    agreement = {"a__old": 0.9, "a__proud": 0.2, "b__old": None, "b__proud": 0.5, "c__old": -0.1}
    entries = [
        ViewerEntry(i, i.split("__")[0], i.split("__")[1], "walk", 20, "", scores={"limb_agreement": v})
        for i, v in agreement.items()
    ]
    assert [e.id for e in choose(entries, worst=2)] == ["c__old", "a__proud"]
    assert [e.id for e in choose(entries, ids=["a"], worst=1)] == ["a__proud"]
    assert [e.id for e in choose(entries, ids=["b__old", "c__old"])] == ["b__old", "c__old"]
    with pytest.raises(MotionDataError, match="no clip with id 'd'"):
        choose(entries, ids=["d"])
    for entry, skate in zip(entries, (0.1, 0.5, 0.3, None, 0.2)):
        entry.scores["foot_skating"] = skate  # lower is better: the worst skate most
    assert [e.id for e in choose(entries, worst=2, by="foot_skating")] == ["a__proud", "b__old"]
    with pytest.raises(MotionDataError, match="unknown score 'nope'"):
        choose(entries, worst=1, by="nope")


def test_limb_agreement_is_one_for_a_retimed_copy_and_lower_for_other_motion() -> None:
    t = np.linspace(0, 2 * np.pi, 60)
    track = np.stack([np.stack([np.sin(t + k), np.cos(2 * t + k), 0.1 * t], axis=1) for k in range(4)], axis=1)
    slow = np.stack(
        [
            np.stack([np.interp(np.linspace(0, 1, 90), np.linspace(0, 1, 60), track[:, j, a]) for a in range(3)], 1)
            for j in range(4)
        ],
        axis=1,
    )
    assert limb_agreement(track, slow) == pytest.approx(1.0, abs=1e-3)
    assert limb_agreement(track, track[::-1]) < 0.5
    assert limb_agreement(track, np.zeros_like(track)) is None


def test_limb_tracks_are_the_ankles_and_wrists_of_the_ric_features(tiny) -> None:
    clip = next(iter(Corpus(tiny["corpus"])))
    joints = features_to_joints(clip.motion)
    tracks = limb_tracks(clip.motion)
    # ric features are root-relative in the root's heading frame: at frame 0 the clip faces +Z, so only x/z shift
    relative = joints[0, [7, 8, 20, 21]] - joints[0, 0] * np.array([1, 0, 1])
    assert np.abs(tracks[0] - relative).max() < 1e-3


def test_corpus_view_and_preview_html_write_the_chosen_clips(tiny, tmp_path: Path) -> None:
    runner = CliRunner()
    ids = [c.id for c in Corpus(tiny["corpus"])][:2]
    result = runner.invoke(
        app, ["corpus", "view", str(tiny["corpus"]), "--ids", ",".join(ids), "--out", str(tmp_path / "c")]
    )
    assert result.exit_code == 0, result.output
    index, records = read_viewer(tmp_path / "c")
    assert index["kind"] == "corpus" and sorted(index["clips"]["id"]) == sorted(ids)
    assert set(records) == {f"src:{i}" for i in ids}
    result = runner.invoke(app, ["preview", str(tiny["run"]), "--html", "--worst", "2", "--out", str(tmp_path / "p")])
    assert result.exit_code == 0, result.output
    assert len(read_viewer(tmp_path / "p")[0]["clips"]["id"]) == 2
    result = runner.invoke(app, ["view", str(tiny["run"]), "--ids", "nope", "--out", str(tmp_path / "n")])
    assert result.exit_code == 1 and "no clip with id 'nope'" in result.output
    result = runner.invoke(app, ["view", str(tiny["corpus"])])
    assert result.exit_code == 2 and "corpus view" in result.output


def test_a_smaller_rebuild_leaves_no_chunk_of_the_last(tiny, tmp_path: Path) -> None:
    write_corpus_viewer(tiny["corpus"], tmp_path, per_chunk=1)
    write_corpus_viewer(tiny["corpus"], tmp_path, ids=[next(iter(Corpus(tiny["corpus"]))).id])
    assert [f.name for f in (tmp_path / "viewer" / "chunks").iterdir()] == ["c00000.js"]


def test_evaluate_writes_the_viewer_and_stands_without_it_when_the_corpus_is_gone(tmp_path: Path) -> None:
    corpus = make_corpus(tmp_path / "corpus", n_clips=10)
    run = build_run(corpus, tmp_path / "run", unit_size=4).output
    runner = CliRunner()
    result = runner.invoke(app, ["evaluate", str(run)])
    assert result.exit_code == 0, result.output
    assert (run / "viewer.html").is_file() and "viewer.html" in (run / "report.md").read_text(encoding="utf-8")
    corpus.rename(tmp_path / "moved")
    (run / "viewer.html").unlink()
    result = runner.invoke(app, ["evaluate", str(run)])
    assert result.exit_code == 0, result.output
    assert "no 3D viewer:" in result.output and "corpus not found" in result.output
    assert not (run / "viewer.html").exists() and (run / "report.html").is_file()
