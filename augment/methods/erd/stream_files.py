"""``motionaug stream``: frames from a BVH or a features ``.npy`` through Style-ERD one at a time, and back out.

Input: a ``.npy`` of (T, 263) HumanML3D features, or a BVH (any rig with a known joint map; retargeted to t2m and
resampled to 20 fps). A BVH is converted as a whole before streaming: retargeting needs its header and the 20 fps
resampling and the features' forward differences need the next source frame, so a BVH file is not a live source.
The network then sees one feature frame at a time (``StreamingStylizer``), exactly as a live feed would give them.
Output: features, one (263,) row per stylized frame as it comes (``.npy`` written at the end, or text lines on
stdout), or a BVH written once the frame count is known.
"""

from __future__ import annotations

import os
import sys
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import BinaryIO, Literal, TextIO

import numpy as np

from motionaug.augment.methods.erd.stream import StreamingStylizer
from motionaug.augment.methods.erd.training import load_erd
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import T2M

OutputFormat = Literal["bvh", "npy", "text"]


def read_frames(source: str | os.PathLike[str] | BinaryIO, kind: Literal["bvh", "npy"]) -> np.ndarray:
    """(T, 263) float32 features from a file path or a binary stream of a BVH or a ``.npy``."""
    if kind == "npy":
        try:
            frames = np.load(source, allow_pickle=False)
        except (OSError, ValueError) as err:
            raise MotionDataError(_name(source), f"not a readable .npy ({str(err).splitlines()[0]})") from None
        if frames.ndim != 2 or frames.shape[1] != T2M.feature_dim:
            raise MotionDataError(_name(source), f"features must be (T, {T2M.feature_dim}), got {frames.shape}")
        return frames.astype(np.float32)
    from motionaug.augment.motion.features import extract_features
    from motionaug.augment.motion.retarget import load_bvh_as_t2m_joints

    if isinstance(source, (str, os.PathLike)):
        joints, _ = load_bvh_as_t2m_joints(source)
    else:
        with tempfile.NamedTemporaryFile(suffix=".bvh") as tmp:
            tmp.write(source.read())
            tmp.flush()
            try:
                joints, _ = load_bvh_as_t2m_joints(tmp.name)
            except MotionDataError as err:  # name the stream, not the temporary file it was copied to
                name = _name(source)
                raise MotionDataError(err.source.replace(tmp.name, name), err.reason.replace(tmp.name, name)) from None
    return extract_features(joints, T2M, source=_name(source))


def stylize_stream(
    frames: Iterable[np.ndarray],
    stylizer: StreamingStylizer,
) -> Iterator[np.ndarray]:
    """Each stylized frame as soon as the stylizer gives it (one frame of lag), then the held last one."""
    for n, frame in enumerate(frames):
        frame = np.asarray(frame, dtype=np.float32)
        if frame.shape != (T2M.feature_dim,):
            raise MotionDataError(f"frame {n}", f"expected {T2M.feature_dim} features, got shape {frame.shape}")
        if not np.isfinite(frame).all():
            raise MotionDataError(f"frame {n}", "NaN or infinite value")
        out = stylizer.step(frame)
        if out is not None:
            yield out
    last = stylizer.flush()
    if last is not None:
        yield last


def run_stream(
    model: Path,
    style: str,
    source: str | os.PathLike[str] | BinaryIO,
    kind: Literal["bvh", "npy"],
    out: str | os.PathLike[str] | TextIO | BinaryIO,
    fmt: OutputFormat,
    intensity: float = 1.0,
) -> int:
    """Stream ``source`` through the network at ``model`` in ``style``; returns the frames written."""
    net = load_erd(model)
    stylizer = StreamingStylizer(net, style, intensity=intensity)
    frames = read_frames(source, kind)
    stylized = stylize_stream(frames, stylizer)
    if fmt == "text":
        stream = out if hasattr(out, "write") else open(out, "w", encoding="utf-8")  # noqa: SIM115
        count = 0
        for frame in stylized:
            stream.write(" ".join(f"{v:.6g}" for v in frame) + "\n")  # type: ignore[union-attr]
            stream.flush()  # type: ignore[union-attr]
            count += 1
        return count
    result = np.stack(list(stylized)).astype(np.float32)
    if fmt == "npy":
        np.save(out if hasattr(out, "write") else Path(out), result)  # type: ignore[arg-type]
        return len(result)
    return _write_bvh(result, out)


def _write_bvh(features: np.ndarray, out: str | os.PathLike[str] | TextIO | BinaryIO) -> int:
    import torch

    from motionaug.augment.motion.bvh import joints_to_bvh
    from motionaug.augment.motion.features import recover_from_ric

    joints = recover_from_ric(torch.from_numpy(features), T2M.n_joints).numpy()
    if hasattr(out, "write"):
        with tempfile.TemporaryDirectory() as folder:
            path = Path(folder) / "out.bvh"
            joints_to_bvh(path, joints, fps=20.0)
            data = path.read_bytes()
        target = getattr(out, "buffer", out)
        target.write(data)  # type: ignore[union-attr]
        target.flush()  # type: ignore[union-attr]
    else:
        joints_to_bvh(out, joints, fps=20.0)
    return len(features)


def _name(source: object) -> str:
    if isinstance(source, (str, os.PathLike)):
        return str(source)
    return getattr(source, "name", "stdin") if source is not sys.stdin.buffer else "stdin"
