"""``motionaug preview`` (GIF/MP4 of a transfer or a corpus clip, PNG grid) and ``export --format bvh``.

Real files throughout: a tiny ``stats`` run on a synthetic corpus (stages called in-process, no Ray).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from fixtures.evaluation.tiny_run import build_run, make_corpus
from PIL import Image
from typer.testing import CliRunner

from motionaug.augment.corpus import Corpus
from motionaug.augment.motion.bvh import read_bvh
from motionaug.augment.motion.features import features_to_joints
from motionaug.augment.outputs.shards import iter_shard_rows, row_motion
from motionaug.augment.render.previews import find_ffmpeg
from motionaug.schemas.skeleton import T2M
from motionaug.workflows.cli import app

PANEL_W, PANEL_H = 320, 360  # render_panels_gif's default panel size


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("preview")
    corpus = make_corpus(root / "corpus", n_clips=10)
    config = build_run(corpus, root / "run", unit_size=4)
    return {"corpus": corpus, "run": config.output}


def invoke(*args: str):
    return CliRunner().invoke(app, [str(a) for a in args])


def frames_of(path: Path) -> list[np.ndarray]:
    with Image.open(path) as image:
        frames = []
        for i in range(image.n_frames):
            image.seek(i)
            frames.append(np.asarray(image.convert("RGB")))
    return frames


def shortest_clip(corpus: Path):
    return min(Corpus(corpus), key=lambda c: c.n_frames)


def test_preview_of_a_transfer_is_side_by_side_at_the_clip_length(tiny, tmp_path: Path) -> None:
    clip = shortest_clip(tiny["corpus"])
    out = tmp_path / "pair.gif"
    result = invoke("preview", tiny["run"], "--clip", clip.id, "--style", "old", "--out", out)
    assert result.exit_code == 0, result.output
    frames = frames_of(out)
    assert len(frames) == clip.n_frames
    assert frames[0].shape == (PANEL_H, 2 * PANEL_W, 3)
    with Image.open(out) as image:
        assert image.info["duration"] == 50  # 20 fps
    body = slice(PANEL_H // 3, PANEL_H)  # below the titles
    ink = [(f[body] < 200).any(axis=-1) for f in frames]  # where anything is drawn (figure, floor, shadow)
    left, right = np.stack([m[:, :PANEL_W] for m in ink]), np.stack([m[:, PANEL_W:] for m in ink])
    assert (left != right).mean() > 0.002  # the stylized pose is not the content pose


def test_preview_of_a_corpus_clip_and_default_output_name(
    tiny, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    clip = shortest_clip(tiny["corpus"])
    monkeypatch.chdir(tmp_path)
    result = invoke("preview", tiny["corpus"], "--clip", clip.id)
    assert result.exit_code == 0, result.output
    frames = frames_of(tmp_path / "previews" / f"{clip.id}.gif")
    assert len(frames) == clip.n_frames and frames[0].shape == (PANEL_H, PANEL_W, 3)


def test_grid_is_one_png_contact_sheet_of_n_transfers(tiny, tmp_path: Path) -> None:
    out = tmp_path / "grid.png"
    result = invoke("preview", tiny["run"], "--grid", 3, "--seed", 1, "--out", out)
    assert result.exit_code == 0, result.output
    with Image.open(out) as image:
        assert image.format == "PNG" and image.size == (
            200 + 6 * 110,
            3 * 2 * 150,
        )  # label + 6 key poses; 3 rows x 2 strips
    again = tmp_path / "again.png"
    invoke("preview", tiny["run"], "--grid", 3, "--seed", 1, "--out", again)
    assert again.read_bytes() == out.read_bytes()  # seeded choice


@pytest.mark.skipif(find_ffmpeg() is None, reason="no ffmpeg (PATH or imageio-ffmpeg) for MP4 previews")
def test_preview_mp4(tiny, tmp_path: Path) -> None:
    clip = shortest_clip(tiny["corpus"])
    out = tmp_path / "pair.mp4"
    result = invoke("preview", tiny["run"], "--clip", clip.id, "--style", "proud", "--out", out)
    assert result.exit_code == 0, result.output
    assert out.read_bytes()[4:8] == b"ftyp"


@pytest.mark.parametrize(
    ("args", "code", "message"),
    [
        (["--clip", "../../etc/passwd", "--style", "old"], 1, "no stylized clip of '../../etc/passwd'"),
        (["--clip", "000001", "--style", "sad"], 1, "run has no style 'sad'"),
        (["--clip", "000001"], 2, "--style"),
        ([], 2, "--clip"),
    ],
)
def test_preview_bad_arguments_are_one_line(tiny, args: list[str], code: int, message: str) -> None:
    result = invoke("preview", tiny["run"], *args)
    assert result.exit_code == code
    assert message in result.output and result.output.count("\n") == 1


def test_unknown_corpus_clip_is_looked_up_not_opened(tiny) -> None:
    result = invoke("preview", tiny["corpus"], "--clip", "../new_joint_vecs/000001")
    assert result.exit_code == 1 and "no clip with id" in result.output


def test_bvh_export_reimports_to_the_same_joints(tiny, tmp_path: Path) -> None:
    out = tmp_path / "bvh"
    result = invoke("export", tiny["run"], "--format", "bvh", "--out", out, "--style", "proud")
    assert result.exit_code == 0, result.output
    rows = {r["output_id"]: r for r in iter_shard_rows(tiny["run"]) if r["style"] == "proud"}
    assert sorted(p.stem for p in out.glob("*.bvh")) == sorted(rows)
    for output_id in sorted(rows)[:3]:
        expected = features_to_joints(row_motion(rows[output_id]))
        motion = read_bvh(out / f"{output_id}.bvh")
        assert motion.fps == pytest.approx(20.0) and sorted(motion.names) == sorted(T2M.joint_names)
        positions = motion.global_positions()[:, [motion.names.index(n) for n in T2M.joint_names]]  # file order -> t2m
        assert np.abs(positions - expected).max() < 1e-3


def test_bvh_export_of_an_unknown_style_fails_in_one_line(tiny, tmp_path: Path) -> None:
    result = invoke("export", tiny["run"], "--format", "bvh", "--out", tmp_path / "x", "--style", "sad")
    assert result.exit_code == 1 and "run has no style 'sad'" in result.output
