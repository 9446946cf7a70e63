"""Style-ERD inference: ``transfer`` (whole clips, batched) and ``StreamingStylizer`` (frame by frame, online).

The network is causal with zero lag: output frame t depends on input frames 0..t. A HumanML3D frame mixes pose t
with forward differences to pose t+1, so with ``rederive_velocities=True`` (default) the output's ``local_vel``
and ``feet`` are recomputed from the stylized poses t and t+1 (the root velocities stay as predicted: they are the
stylized trajectory) and frame t is emitted once t+1 exists, exactly one frame (50 ms at 20 fps) of lag; ``flush``
returns the last frame with the network's own velocities; ``rederive_velocities=False`` has no lag. Each stylized
6D rotation is projected back onto a rotation. The channel-by-channel table: docs/internals.md.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from motionaug.augment.motion.features import DEFAULT_FEET_THRESHOLD, feature_slices
from motionaug.models.style_erd import NEUTRAL, ErdNetwork, ErdState
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import T2M

_SL = feature_slices(T2M)
_J = T2M.n_joints
_FEET = list(T2M.feet_left) + list(T2M.feet_right)  # [l ankle, l toe, r ankle, r toe], as the extractor
FORWARD_CHANNELS = {name: _SL[name] for name in ("root_rot_vel", "root_lin_vel", "local_vel", "feet")}
"""Channels of frame t that depend on pose t+1 (see the module docstring)."""


# ---- per-frame output finishing (shared by transfer and the stream, so both give the same frames) ----------


def project_rotations(frames: np.ndarray) -> np.ndarray:
    """Copy of ``frames`` (..., 263) whose 6D rotations are Gram-Schmidt orthonormal (first column unit, second
    unit and orthogonal to it), the matrix ``cont6d_to_matrix`` would build from them."""
    out = np.array(frames, dtype=np.float32, copy=True)
    d6 = out[..., _SL["rot"]].reshape(out.shape[:-1] + (_J - 1, 6)).astype(np.float64)
    a, b = d6[..., :3], d6[..., 3:]
    a = a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1e-8)
    b = b - (a * b).sum(-1, keepdims=True) * a
    b = b / np.maximum(np.linalg.norm(b, axis=-1, keepdims=True), 1e-8)
    out[..., _SL["rot"]] = np.concatenate([a, b], axis=-1).reshape(out.shape[:-1] + (-1,))
    return out


def rederive_forward(cur: np.ndarray, nxt: np.ndarray, feet_threshold: float = DEFAULT_FEET_THRESHOLD) -> np.ndarray:
    """Frame(s) ``cur`` (..., 263) with ``local_vel`` and ``feet`` recomputed from poses ``cur`` and ``nxt``.

    ``local_vel[t] = R_t (p_{t+1} - p_t)`` in the extractor; written with frame-local quantities only:
    ``R_t R_{t+1}^-1 (ric_{t+1} + [vx_t, 0, vz_t]) - ric_t`` where ``ric`` includes the root joint
    ``(0, root_y, 0)`` and ``R_t R_{t+1}^-1`` is the yaw by ``-2 * root_rot_vel[t]`` (the channel holds the half
    angle). Contacts: the squared foot step, ``|local_vel|^2`` (rotation keeps lengths), below the threshold.
    No global integration, so a stream and a whole clip give the same numbers.
    """
    c = np.asarray(cur, dtype=np.float64)
    n = np.asarray(nxt, dtype=np.float64)
    lead = c.shape[:-1]

    def ric_full(f: np.ndarray) -> np.ndarray:
        root = np.zeros(lead + (1, 3))
        root[..., 0, 1] = f[..., _SL["root_y"].start]
        return np.concatenate([root, f[..., _SL["ric"]].reshape(lead + (_J - 1, 3))], axis=-2)

    step = ric_full(n)
    step[..., 0] += c[..., 1, None]
    step[..., 2] += c[..., 2, None]
    angle = 2.0 * c[..., 0, None]
    cos, sin = np.cos(angle), np.sin(angle)
    rotated = np.stack(
        [cos * step[..., 0] - sin * step[..., 2], step[..., 1], sin * step[..., 0] + cos * step[..., 2]], -1
    )
    local_vel = rotated - ric_full(c)
    out = np.array(cur, dtype=np.float32, copy=True)
    out[..., _SL["local_vel"]] = local_vel.reshape(lead + (-1,))
    out[..., _SL["feet"]] = ((local_vel[..., _FEET, :] ** 2).sum(-1) < feet_threshold).astype(np.float32)
    return out


def finish_clip(frames: np.ndarray, rederive_velocities: bool = True) -> np.ndarray:
    """Whole-clip version of what the stream does per frame: project rotations, re-derive frames 0..T-2."""
    out = project_rotations(frames)
    if rederive_velocities and len(out) > 1:
        out[:-1] = rederive_forward(out[:-1], out[1:])
    return out


# ---- conditioning and checks ----------------------------------------------------------------------------------


def _style_index(net: ErdNetwork, style: str, what: str = "style") -> int:
    try:
        return net.style_index(style)
    except KeyError:
        raise MotionDataError(f"{what} {style!r}", f"unknown style; known: {list(net.config.styles)}") from None


def _content_index(net: ErdNetwork, content: str | None) -> int:
    try:
        return net.content_index(content)
    except KeyError:
        known = list(net.config.contents)
        raise MotionDataError(f"content {content!r}", f"unknown content; known: {known} or None") from None


def _unit(value: float, name: str) -> float:
    value = float(value)
    if not 0.0 <= value <= 1.0:
        raise MotionDataError(name, f"{value} outside [0, 1]")
    return value


def target_mixture(
    net: ErdNetwork, style: str, intensity: float = 1.0, blend_with: str | None = None, alpha: float = 1.0
) -> torch.Tensor:
    """Checked sec. 4.4 target mixture (n_styles,); see ``ErdNetwork.mixture``."""
    _style_index(net, style)
    if blend_with is not None:
        _style_index(net, blend_with, "blend style")
    return net.mixture(style, _unit(intensity, "intensity"), blend_with, _unit(alpha, "alpha")).detach()


def _conditions(
    net: ErdNetwork, source_style: str | None, source_content: str | None
) -> tuple[torch.Tensor, torch.Tensor]:
    src = net.style_onehot(torch.tensor([_style_index(net, source_style or NEUTRAL, "source style")]))
    content = net.content_onehot(torch.tensor([_content_index(net, source_content)]))
    return src, content


def _check_motion(motion: np.ndarray, dim: int, source: str) -> np.ndarray:
    arr = np.asarray(motion)
    if arr.ndim != 2 or arr.shape[1] != dim or arr.shape[0] < 1:
        raise MotionDataError(source, f"expected (T >= 1, {dim}) features, got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number) or not np.isfinite(arr).all():
        raise MotionDataError(source, "features contain NaN or infinite values")
    return arr.astype(np.float32, copy=False)


# ---- offline ----------------------------------------------------------------------------------------------------


def transfer(
    net: ErdNetwork,
    motions: Sequence[np.ndarray],
    target_style: str,
    source_style: str | None = None,
    source_content: str | None = None,
    *,
    intensity: float = 1.0,
    blend_with: str | None = None,
    alpha: float = 1.0,
    batch_size: int = 64,
    rederive_velocities: bool = True,
) -> list[np.ndarray]:
    """Stylize whole clips offline; the same frames ``StreamingStylizer`` emits for each clip.

    ``motions``: (T, 263) float32 un-normalised HumanML3D features. ``source_style`` None = neutral (supp. C.4:
    unlabelled input is treated as neutral); ``source_content`` None = the learned unknown-content state.
    ``intensity`` / ``blend_with`` + ``alpha``: sec. 4.4 style intensity and blending. Clips are batched (up to
    ``batch_size``, longest first) and padded at the end; the LSTMs are causal, so padding never changes a frame.
    Returns one (T, 263) float32 array per input, in order.
    """
    dim = net.config.frame_dim
    arrays = [_check_motion(m, dim, f"motion {i}") for i, m in enumerate(motions)]
    target = target_mixture(net, target_style, intensity, blend_with, alpha)
    src, content = _conditions(net, source_style, source_content)
    mean, std = net.mean.detach().numpy(), net.std.detach().numpy()
    order = sorted(range(len(arrays)), key=lambda i: -len(arrays[i]))
    out: list[np.ndarray | None] = [None] * len(arrays)
    for start in range(0, len(order), max(1, batch_size)):
        idx = order[start : start + max(1, batch_size)]
        longest = len(arrays[idx[0]])
        batch = np.zeros((len(idx), longest, dim), dtype=np.float32)  # zero = the corpus mean after normalising
        for row, i in enumerate(idx):
            batch[row, : len(arrays[i])] = (arrays[i] - mean) / std
        rows = len(idx)
        with torch.inference_mode():
            y, _ = net(
                torch.from_numpy(batch),
                src.expand(rows, -1),
                content.expand(rows, -1),
                target.expand(rows, -1),
                skip_idle=True,
            )
        y = y.numpy() * std + mean
        for row, i in enumerate(idx):
            out[i] = finish_clip(y[row, : len(arrays[i])], rederive_velocities)
    return [o for o in out if o is not None]


# ---- online -----------------------------------------------------------------------------------------------------


class StreamingStylizer:
    """Online Style-ERD: one feature frame in, one stylized frame out, one frame of lag (see the module docstring).

    ``step(frame)`` takes a (263,) un-normalised frame and returns the stylized previous frame (``None`` for the
    first one; no lag when ``rederive_velocities=False``). ``flush()`` returns the held last frame at the end of
    a stream; ``reset()`` starts a new stream from the learned initial state; ``set_style`` changes the target
    mid-stream. Every style branch advances on every frame, so a change takes effect at the next frame with that
    branch's full memory of the stream: the output equals ``ErdNetwork.forward`` with the per-frame schedule of
    targets. Bad input raises ``MotionDataError`` (``source: reason``) and leaves the stream untouched.
    """

    def __init__(
        self,
        net: ErdNetwork,
        style: str,
        intensity: float = 1.0,
        source_style: str | None = None,
        source_content: str | None = None,
        rederive_velocities: bool = True,
    ) -> None:
        self.net = net
        self.dim = net.config.frame_dim
        self.rederive_velocities = rederive_velocities
        self._mean = net.mean.detach().numpy().astype(np.float32)
        self._std = net.std.detach().numpy().astype(np.float32)
        self._source, self._content = _conditions(net, source_style, source_content)
        self._target = target_mixture(net, style, intensity)[None]
        self.style = style
        self.reset()

    @property
    def lag(self) -> int:
        """Frames between a frame going in and its stylized version coming out of ``step``."""
        return 1 if self.rederive_velocities else 0

    @property
    def frames_seen(self) -> int:
        return self._seen

    @property
    def state(self) -> ErdState:
        return self._state

    def reset(self) -> None:
        """Forget the stream: learned initial state, nothing pending. The target style is kept."""
        with torch.inference_mode():
            self._state = self.net.initial_state(self._content)
        self._pending: np.ndarray | None = None
        self._seen = 0

    def set_style(self, style: str, intensity: float = 1.0, blend_with: str | None = None, alpha: float = 1.0) -> None:
        """New target from the next frame on: ``intensity`` x (``alpha`` ``style`` + (1 - ``alpha``) ``blend_with``)."""
        self._target = target_mixture(self.net, style, intensity, blend_with, alpha)[None]
        self.style = style

    def step(self, frame: np.ndarray) -> np.ndarray | None:
        """Feed one (263,) frame; get the stylized frame ``lag`` frames back, or ``None`` while waiting."""
        source = f"stream frame {self._seen}"
        arr = np.asarray(frame)
        if arr.shape != (self.dim,):
            raise MotionDataError(source, f"expected shape ({self.dim},), got {arr.shape}")
        if not np.issubdtype(arr.dtype, np.number) or not np.isfinite(arr).all():
            raise MotionDataError(source, "frame contains NaN or infinite values")
        x = torch.from_numpy(((arr.astype(np.float32) - self._mean) / self._std)[None])
        with torch.inference_mode():
            y, self._state = self.net.step(x, self._state, self._source, self._content, self._target)
        out = project_rotations(y[0].numpy() * self._std + self._mean)
        self._seen += 1
        if not self.rederive_velocities:
            return out
        prev, self._pending = self._pending, out
        return None if prev is None else rederive_forward(prev, out)

    def flush(self) -> np.ndarray | None:
        """End of stream: the held last frame (network-predicted velocities and contacts), or ``None``."""
        out, self._pending = self._pending, None
        return out
