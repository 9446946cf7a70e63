"""Motion previews: GIF/MP4 animations and contact sheets, checked on their pixels and metadata."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.render.previews import (
    STYLIZED_COLOR,
    Camera,
    Panel,
    SheetRow,
    features_to_joints,
    preview_clip,
    preview_pair,
    render_contact_sheet,
    render_panels_gif,
)
from motionaug.schemas.captions import Caption
from motionaug.schemas.errors import MotionDataError

torch.set_num_threads(1)
FIXTURES = Path(__file__).resolve().parent / "fixtures" / "humanml3d"
REPO = Path(__file__).resolve().parents[1]
SMALL = (120, 150)  # one panel's pixels: small keeps the tests fast


@pytest.fixture(scope="module")
def features() -> np.ndarray:
    return np.load(FIXTURES / "new_joint_vecs" / "012314.npy")


@pytest.fixture(scope="module")
def joints(features: np.ndarray) -> np.ndarray:
    return features_to_joints(features)


def gif_frames(path: Path) -> list[np.ndarray]:
    with Image.open(path) as image:
        frames = []
        for k in range(image.n_frames):
            image.seek(k)
            frames.append(np.asarray(image.convert("RGB")))
    return frames


def halves(frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    width = frame.shape[1] // 2
    return frame[:, :width], frame[:, width:]


def no_temp_files(directory: Path) -> bool:
    return not list(directory.glob(".*.tmp"))


def test_features_to_joints_matches_dataset_joints(features: np.ndarray, joints: np.ndarray) -> None:
    expected = np.load(FIXTURES / "new_joints" / "012314.npy")
    assert joints.shape == (170, 22, 3) and joints.dtype == np.float32
    np.testing.assert_allclose(joints, expected, atol=1e-4)


@pytest.mark.parametrize("bad", [np.zeros((10, 262), np.float32), np.zeros((263,), np.float32), np.zeros((0, 263))])
def test_features_to_joints_rejects_bad_shapes(bad: np.ndarray) -> None:
    with pytest.raises(MotionDataError, match="clip x"):
        features_to_joints(bad, source="clip x")


def test_gif_frame_count_size_and_duration(joints: np.ndarray, tmp_path: Path) -> None:
    out = render_panels_gif([Panel(joints[:24], "one")], tmp_path / "a.gif", fps=20, size=SMALL)
    with Image.open(out) as image:
        assert image.n_frames == 24
        assert image.size == SMALL
        assert image.info["duration"] == 50
        assert image.info["loop"] == 0
    assert no_temp_files(tmp_path)


def test_gif_stride_max_frames_and_wide_layout(joints: np.ndarray, tmp_path: Path) -> None:
    panels = [Panel(joints[:25], "a"), Panel(joints[5:30], "b", STYLIZED_COLOR)]
    out = render_panels_gif(panels, tmp_path / "s.gif", fps=25, size=SMALL, stride=4)
    with Image.open(out) as image:
        assert image.n_frames == math.ceil(25 / 4)
        assert image.size == (2 * SMALL[0], SMALL[1])
        assert image.info["duration"] == 160  # 4 frames at 25 fps: playback stays real time
    capped = render_panels_gif(panels, tmp_path / "m.gif", fps=25, size=SMALL, max_frames=5)
    with Image.open(capped) as image:
        assert image.n_frames == 5


def test_identical_panels_give_identical_halves(joints: np.ndarray, tmp_path: Path) -> None:
    panel = Panel(joints[40:60], "same caption", STYLIZED_COLOR)
    frames = gif_frames(render_panels_gif([panel, panel], tmp_path / "same.gif", size=SMALL))
    assert len(frames) == 20
    for frame in frames:
        left, right = halves(frame)
        np.testing.assert_array_equal(left, right)
    assert not np.array_equal(frames[0], frames[-1])  # it does move


@pytest.mark.parametrize("camera", [Camera(), Camera(follow=False)], ids=["follow", "fixed"])
def test_different_motion_gives_different_halves(joints: np.ndarray, tmp_path: Path, camera: Camera) -> None:
    panels = [Panel(joints[40:60], "same"), Panel(joints[100:120], "same")]
    frames = gif_frames(render_panels_gif(panels, tmp_path / "diff.gif", size=SMALL, camera=camera))
    for frame in frames:
        left, right = halves(frame)
        assert np.abs(left.astype(int) - right.astype(int)).sum(axis=-1).astype(bool).mean() > 0.005


def test_shorter_panel_holds_its_last_frame(joints: np.ndarray, tmp_path: Path) -> None:
    panels = [Panel(joints[:20], "long"), Panel(joints[60:70], "short", STYLIZED_COLOR)]
    frames = gif_frames(render_panels_gif(panels, tmp_path / "hold.gif", size=SMALL))
    assert len(frames) == 20
    held = [halves(f)[1] for f in frames[9:]]
    for right in held[1:]:
        np.testing.assert_array_equal(right, held[0])
    assert not np.array_equal(halves(frames[9])[0], halves(frames[19])[0])


def colour_pixels(image: np.ndarray, rgb: tuple[float, float, float], tol: int = 12) -> np.ndarray:
    """(row, col) of pixels within ``tol`` of a colour."""
    target = np.round(np.array(rgb) * 255).astype(int)
    return np.argwhere(np.abs(image.astype(int) - target).max(axis=-1) <= tol)


def test_figure_is_upright_and_not_mirrored(joints: np.ndarray, tmp_path: Path) -> None:
    """Frame 0 faces the camera (+Z): the light left limbs must appear right of the dark right limbs."""
    still = np.repeat(joints[:1], 3, axis=0)
    still[..., 0] -= still[:, :1, 0]
    frame = gif_frames(render_panels_gif([Panel(still, "", "#00a000")], tmp_path / "lr.gif", size=(200, 240)))[0]
    left = colour_pixels(frame, (0.45, 0.45 + 0.55 * 160 / 255, 0.45))
    right = colour_pixels(frame, (0.0, 0.55 * 160 / 255, 0.0))
    centre = colour_pixels(frame, (0.0, 160 / 255, 0.0))
    assert len(left) > 20 and len(right) > 20 and len(centre) > 10
    assert left[:, 1].mean() > right[:, 1].mean() + 5
    head_row = centre[:, 0].min()
    feet_row = max(left[:, 0].max(), right[:, 0].max())
    assert feet_row - head_row > 60  # head on top, well above the feet


def test_mp4_without_ffmpeg_is_a_clear_error(
    joints: np.ndarray, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import motionaug.augment.render.previews as previews

    monkeypatch.setattr(previews, "find_ffmpeg", lambda: None)
    with pytest.raises(MotionDataError, match="ffmpeg"):
        render_panels_gif([Panel(joints[:5], "x")], tmp_path / "a.mp4", size=SMALL)
    assert not (tmp_path / "a.mp4").exists()


def test_mp4_with_ffmpeg(joints: np.ndarray, tmp_path: Path) -> None:
    out = render_panels_gif([Panel(joints[:10], "x"), Panel(joints[:10], "y")], tmp_path / "a.mp4", size=(121, 151))
    data = out.read_bytes()
    assert data[4:8] == b"ftyp"
    assert no_temp_files(tmp_path)


def test_bad_inputs_raise_motion_data_error(joints: np.ndarray, tmp_path: Path) -> None:
    good = Panel(joints[:5], "ok")
    with pytest.raises(MotionDataError, match="unsupported preview format"):
        render_panels_gif([good], tmp_path / "a.avi")
    with pytest.raises(MotionDataError, match="no panels"):
        render_panels_gif([], tmp_path / "a.gif")
    with pytest.raises(MotionDataError, match="21 joints"):
        render_panels_gif([Panel(joints[:5, :21], "kit?")], tmp_path / "a.gif")
    with pytest.raises(MotionDataError, match="stride"):
        render_panels_gif([good], tmp_path / "a.gif", stride=0)
    with pytest.raises(MotionDataError, match="NaN"):
        Panel(np.full((3, 22, 3), np.nan), "nan")
    with pytest.raises(MotionDataError, match=r"\(T>=1, J, 3\)"):
        Panel(np.zeros((3, 22)), "flat")
    with pytest.raises(ValueError):
        Panel(joints[:3], "x", color="not-a-colour")
    assert not list(tmp_path.iterdir())


def test_contact_sheet_size_and_rows(joints: np.ndarray, tmp_path: Path) -> None:
    rows = [
        SheetRow(
            "proud | 012314 | a person walks",
            [Panel(joints[:60], "content"), Panel(joints[60:120], "stylized", STYLIZED_COLOR)],
        ),
        SheetRow("old | 012314", [Panel(joints[100:170], "content")]),
    ]
    cell, label_width, n = (80, 110), 150, 4
    out = render_contact_sheet(rows, tmp_path / "sheet.png", n_keyposes=n, cell_size=cell, label_width=label_width)
    image = np.asarray(Image.open(out).convert("RGB"))
    assert image.shape == (3 * cell[1], label_width + n * cell[0], 3)
    dark = image.min(axis=-1) < 150
    for strip in range(3):  # every strip shows a pose in every cell
        band = dark[strip * cell[1] + 14 : (strip + 1) * cell[1] - 14, label_width:]
        for k in range(n):
            assert band[:, k * cell[0] : (k + 1) * cell[0]].sum() > 30, (strip, k)
    assert dark[: 2 * cell[1], :label_width].any() and dark[2 * cell[1] :, :label_width].any()  # row labels
    assert not dark[cell[1] + 5 : 2 * cell[1] - 5, 5:label_width].any()  # a two-panel row has one label
    assert no_temp_files(tmp_path)


def test_contact_sheet_rejects_bad_requests(joints: np.ndarray, tmp_path: Path) -> None:
    row = SheetRow("r", [Panel(joints[:10], "p")])
    with pytest.raises(MotionDataError, match="PNG"):
        render_contact_sheet([row], tmp_path / "s.gif")
    with pytest.raises(MotionDataError, match="n_keyposes"):
        render_contact_sheet([row], tmp_path / "s.png", n_keyposes=0)
    with pytest.raises(MotionDataError, match="no panels"):
        SheetRow("empty", [])


def test_preview_clip_and_pair_from_features(features: np.ndarray, tmp_path: Path) -> None:
    caption = Caption(text="a person moves about")
    clip = MotionClip("012314", features[:30], [caption], fps=20.0)
    with Image.open(preview_clip(clip, tmp_path / "clip.gif", size=SMALL)) as image:
        assert (image.n_frames, image.size, image.info["duration"]) == (30, SMALL, 50)
    stylized = MotionClip("012314_proud", features[40:60], [Caption(text="proudly")], fps=20.0, style="proud")
    with Image.open(preview_pair(clip, stylized, None, None, tmp_path / "pair.gif", size=SMALL)) as image:
        assert (image.n_frames, image.size) == (30, (2 * SMALL[0], SMALL[1]))
    out = preview_pair(clip, features[:30], caption, "stylized text", tmp_path / "same.gif", size=SMALL, stride=10)
    frames = gif_frames(out)
    assert len(frames) == 3
    left, right = halves(frames[1])
    assert not np.array_equal(left, right)  # same motion, but the titles and colours differ


def test_import_leaves_pyplot_alone() -> None:
    code = "import sys, motionaug.augment.render.previews; sys.exit('matplotlib.pyplot' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], cwd=REPO).returncode == 0
