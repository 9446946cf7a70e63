"""``motionaug stream``: a BVH through a (tiny, really trained) Style-ERD frame by frame, and bad input as one line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from motionaug.augment.corpus import Corpus
from motionaug.augment.methods.erd.method import ErdMethod
from motionaug.augment.methods.erd.stream import StreamingStylizer, transfer
from motionaug.augment.methods.erd.stream_files import read_frames, stylize_stream
from motionaug.augment.methods.erd.training import ErdTrain, load_erd, train_erd
from motionaug.augment.motion.bvh import read_bvh
from motionaug.augment.synth import generate_corpus
from motionaug.workflows.cli import app

WALK = Path(__file__).resolve().parent / "fixtures" / "bvh" / "dataset-1" / "data" / "dataset-1_walk_normal_002.bvh"


@pytest.fixture(scope="module")
def model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("stream")
    generate_corpus(root / "corpus", 24, seed=0)
    config = ErdTrain(**ErdMethod.smoke_params["train"]).recipe("tiny")
    return train_erd(list(Corpus(root / "corpus")), root / "erd", config)


def test_bvh_in_bvh_out_through_stdin_and_stdout(model: Path) -> None:
    style = next(s for s in load_erd(model).config.styles if s != "neutral")
    result = CliRunner().invoke(app, ["stream", "--style", style, "--model", str(model)], input=WALK.read_bytes())
    assert result.exit_code == 0, result.output
    text = result.stdout
    assert text.startswith("HIERARCHY") and "MOTION" in text
    frames = read_frames(WALK, "bvh")
    assert f"Frames: {len(frames)}" in text  # one stylized frame per input frame (the last one flushed)


def test_streamed_frames_equal_the_offline_transfer(model: Path, tmp_path: Path) -> None:
    net = load_erd(model)
    style = net.config.styles[-1]
    frames = read_frames(WALK, "bvh")
    streamed = np.stack(list(stylize_stream(frames, StreamingStylizer(net, style))))
    (offline,) = transfer(net, [frames], style)
    np.testing.assert_allclose(streamed, offline, atol=1e-5)
    out = tmp_path / "x.npy"
    np.save(tmp_path / "in.npy", frames)
    result = CliRunner().invoke(
        app, ["stream", "--style", style, "--model", str(model), "--input", str(tmp_path / "in.npy"), "--out", str(out)]
    )
    assert result.exit_code == 0, result.output
    np.testing.assert_allclose(np.load(out), offline, atol=1e-5)
    assert read_bvh(WALK).n_frames > 0


@pytest.mark.parametrize(
    ("content", "style", "expected"),
    [
        (np.zeros((5, 100), np.float32), None, "features must be (T, 263)"),
        (np.full((5, 263), np.nan, np.float32), None, "NaN"),
        (np.zeros((5, 263), np.float32), "no-such-style", "unknown style"),
    ],
)
def test_bad_input_is_one_line(
    model: Path, tmp_path: Path, content: np.ndarray, style: str | None, expected: str
) -> None:
    path = tmp_path / "in.npy"
    np.save(path, content)
    style = style or load_erd(model).config.styles[-1]
    result = CliRunner().invoke(app, ["stream", "--style", style, "--model", str(model), "--input", str(path)])
    assert result.exit_code == 1
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and expected in lines[0] and "Traceback" not in result.output
