"""BVH motion files: a strict reader, forward kinematics, and writers (generic and t2m joints).

Conventions match Blender's and MotionBuilder's reading of the format: rotation channels are intrinsic, applied in
channel order (``Zrotation Xrotation Yrotation`` is ``R = Rz @ Rx @ Ry`` on column vectors, degrees); position
channels, on any joint, replace the OFFSET on the axes they name (the Bandai Namco files rely on it); End Sites are
not joints but are kept in ``BvhMotion.end_sites`` so a writer can restore them; quaternions are (w, x, y, z), as in
HumanML3D. The reader is strict on purpose: a truncated or garbled file raises ``MotionDataError`` naming the file
and the first problem with its line number, instead of yielding a silently wrong clip.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import chain
from pathlib import Path

import numpy as np

from motionaug.augment.io import atomic_write_text
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import T2M, Skeleton

_AXIS = {"X": 0, "Y": 1, "Z": 2}
_CHANNELS = {f"{a}{kind}".lower(): f"{a}{kind}" for a in "XYZ" for kind in ("position", "rotation")}
_FRAMES = re.compile(r"^\s*Frames\s*:\s*(\S+)\s*$", re.IGNORECASE)
_FRAME_TIME = re.compile(r"^\s*Frame\s+Time\s*:\s*(\S+)\s*$", re.IGNORECASE)
_MOTION = re.compile(r"^[ \t]*MOTION[ \t\r]*$", re.MULTILINE)


@dataclass(frozen=True)
class BvhMotion:
    """A parsed BVH file: joint tree, channel layout and the raw frame values.

    Joints are in file (depth-first) order, so ``parents[j] < j``. ``frames`` is (F, C) float64
    with the channels of joint 0 first, exactly as in the file.
    """

    source: str
    names: list[str]
    parents: list[int]
    offsets: np.ndarray  # (J, 3)
    channels: list[tuple[str, ...]]
    frame_time: float
    frames: np.ndarray  # (F, C)
    end_sites: dict[int, np.ndarray] = field(default_factory=dict)

    @property
    def n_joints(self) -> int:
        return len(self.names)

    @property
    def n_frames(self) -> int:
        return int(self.frames.shape[0])

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time

    def channel_starts(self) -> list[int]:
        """Column of each joint's first channel in ``frames``."""
        starts, col = [], 0
        for chans in self.channels:
            starts.append(col)
            col += len(chans)
        return starts

    def local_rotations(self) -> np.ndarray:
        """(F, J, 3, 3) rotation of each joint relative to its parent, from its rotation channels."""
        rot = np.broadcast_to(np.eye(3), (self.n_frames, self.n_joints, 3, 3)).copy()
        for j, (start, chans) in enumerate(zip(self.channel_starts(), self.channels)):
            for k, name in enumerate(chans):
                if name.endswith("rotation"):
                    angle = np.deg2rad(self.frames[:, start + k])
                    rot[:, j] = rot[:, j] @ axis_rotation(name[0], angle)
        return rot

    def local_quaternions(self) -> np.ndarray:
        """(F, J, 4) local rotations as unit quaternions (w, x, y, z), w >= 0."""
        return matrix_to_quat(self.local_rotations())

    def local_translations(self) -> np.ndarray:
        """(F, J, 3) joint origin in its parent's frame: OFFSET, replaced by position channels."""
        trans = np.broadcast_to(self.offsets, (self.n_frames, self.n_joints, 3)).copy()
        for j, (start, chans) in enumerate(zip(self.channel_starts(), self.channels)):
            for k, name in enumerate(chans):
                if name.endswith("position"):
                    trans[:, j, _AXIS[name[0]]] = self.frames[:, start + k]
        return trans

    def global_transforms(self) -> tuple[np.ndarray, np.ndarray]:
        """World rotations (F, J, 3, 3) and positions (F, J, 3) by forward kinematics."""
        return forward_kinematics(self.parents, self.local_rotations(), self.local_translations())

    def global_positions(self) -> np.ndarray:
        """(F, J, 3) joint positions in file units and axes."""
        return self.global_transforms()[1]


# --------------------------------------------------------------------------- rotation math


def axis_rotation(axis: str, angle: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation by ``angle`` radians about the named axis (right-handed)."""
    c, s = np.cos(angle), np.sin(angle)
    one, zero = np.ones_like(angle), np.zeros_like(angle)
    rows = {
        "X": [[one, zero, zero], [zero, c, -s], [zero, s, c]],
        "Y": [[c, zero, s], [zero, one, zero], [-s, zero, c]],
        "Z": [[c, -s, zero], [s, c, zero], [zero, zero, one]],
    }[axis]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def euler_to_matrix(angles_deg: np.ndarray, order: str) -> np.ndarray:
    """(..., 3, 3) from intrinsic angles in degrees applied in ``order`` (e.g. "ZXY")."""
    rad = np.deg2rad(angles_deg)
    out = axis_rotation(order[0], rad[..., 0])
    for k in (1, 2):
        out = out @ axis_rotation(order[k], rad[..., k])
    return out


def matrix_to_euler(rot: np.ndarray, order: str) -> np.ndarray:
    """(..., 3) intrinsic angles in degrees for ``order`` (a permutation of XYZ).

    Uses atan2 for every angle so precision holds near gimbal lock; at lock the last angle is 0.
    """
    _check_order(order)
    i, j, k = (_AXIS[a] for a in order)
    sign = 1.0 if (j - i) % 3 == 1 else -1.0  # even permutation of XYZ
    cos_mid = np.hypot(rot[..., i, i], rot[..., i, j])
    mid = np.arctan2(sign * rot[..., i, k], cos_mid)
    first = np.arctan2(-sign * rot[..., j, k], rot[..., k, k])
    last = np.arctan2(-sign * rot[..., i, j], rot[..., i, i])
    locked = cos_mid < 1e-9
    first = np.where(locked, np.arctan2(sign * rot[..., k, j], rot[..., j, j]), first)
    last = np.where(locked, 0.0, last)
    return np.rad2deg(np.stack([first, mid, last], axis=-1))


def quat_to_matrix(quat: np.ndarray) -> np.ndarray:
    """(..., 3, 3) from (..., 4) quaternions (w, x, y, z); normalises first."""
    q = quat / np.linalg.norm(quat, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def matrix_to_quat(rot: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions (w, x, y, z) with w >= 0 from rotation matrices.

    Picks the largest of the four squared components per element (Shepperd) to stay accurate.
    """
    m = rot
    trace = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    d0, d1, d2 = (1 + 2 * m[..., i, i] - trace for i in range(3))
    xw, yw, zw = m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]
    xy, xz, yz = m[..., 0, 1] + m[..., 1, 0], m[..., 0, 2] + m[..., 2, 0], m[..., 1, 2] + m[..., 2, 1]
    cands = np.stack(
        [
            np.stack([1 + trace, xw, yw, zw], -1),
            np.stack([xw, d0, xy, xz], -1),
            np.stack([yw, xy, d1, yz], -1),
            np.stack([zw, xz, yz, d2], -1),
        ],
        axis=-2,
    )  # (..., 4 candidates, 4); candidate c is 4 q_c * q, accurate when q_c is the largest
    diag = np.stack([1 + trace, d0, d1, d2], -1)
    best = np.argmax(diag, axis=-1)
    q = np.take_along_axis(cands, best[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def forward_kinematics(
    parents: Sequence[int], local_rot: np.ndarray, local_trans: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """World rotations (F, J, 3, 3) and positions (F, J, 3); needs ``parents[j] < j``."""
    glob_rot = np.empty_like(local_rot)
    glob_pos = np.empty_like(local_trans)
    for j, p in enumerate(parents):
        if p < 0:
            glob_rot[:, j] = local_rot[:, j]
            glob_pos[:, j] = local_trans[:, j]
        else:
            glob_rot[:, j] = glob_rot[:, p] @ local_rot[:, j]
            glob_pos[:, j] = glob_pos[:, p] + np.einsum("fab,fb->fa", glob_rot[:, p], local_trans[:, j])
    return glob_rot, glob_pos


def _check_order(order: str) -> None:
    if sorted(order) != ["X", "Y", "Z"]:
        raise ValueError(f"rotation order must be a permutation of XYZ, got {order!r}")


# --------------------------------------------------------------------------- reader


class _Tokens:
    """Whitespace tokens of the HIERARCHY section with their 1-based line numbers."""

    def __init__(self, text: str, source: str) -> None:
        self.source = source
        self.items = [(tok, n) for n, line in enumerate(text.splitlines(), 1) for tok in line.split()]
        self.pos = 0

    def fail(self, reason: str) -> MotionDataError:
        line = self.items[min(self.pos, len(self.items) - 1)][1] if self.items else 1
        return MotionDataError(self.source, f"line {line}: {reason}")

    def peek(self) -> str | None:
        return self.items[self.pos][0] if self.pos < len(self.items) else None

    def take(self, what: str) -> str:
        if self.pos >= len(self.items):
            raise MotionDataError(self.source, f"hierarchy ends early, expected {what}")
        tok = self.items[self.pos][0]
        self.pos += 1
        return tok

    def expect(self, keyword: str) -> None:
        tok = self.take(keyword)
        if tok.upper() != keyword.upper():
            self.pos -= 1
            raise self.fail(f"expected {keyword!r}, found {tok!r}")

    def rest_of_line(self, what: str) -> str:
        """Joint names may contain spaces: take tokens up to the end of the line (or a '{')."""
        if self.pos >= len(self.items):
            raise MotionDataError(self.source, f"hierarchy ends early, expected {what}")
        line = self.items[self.pos][1]
        parts = []
        while self.pos < len(self.items) and self.items[self.pos][1] == line and self.items[self.pos][0] != "{":
            parts.append(self.items[self.pos][0])
            self.pos += 1
        return " ".join(parts)

    def number(self, what: str) -> float:
        tok = self.take(what)
        try:
            value = float(tok)
        except ValueError:
            self.pos -= 1
            raise self.fail(f"expected a number for {what}, found {tok!r}") from None
        if not np.isfinite(value):
            self.pos -= 1
            raise self.fail(f"{what} is not finite ({tok!r})")
        return value


@dataclass
class _Tree:
    names: list[str] = field(default_factory=list)
    parents: list[int] = field(default_factory=list)
    offsets: list[list[float]] = field(default_factory=list)
    channels: list[tuple[str, ...]] = field(default_factory=list)
    end_sites: dict[int, np.ndarray] = field(default_factory=dict)


MAX_JOINTS = 1024  # a human rig has tens to a few hundred (fingers, face); more is not a skeleton
MAX_DEPTH = 128  # joints from the root to a leaf: a spine and a finger chain are far below this


def _parse_joint(tok: _Tokens, tree: _Tree, parent: int, depth: int = 1) -> None:
    """Parse one ROOT/JOINT block (name already at the cursor) and its children, recursively (``MAX_DEPTH`` deep
    at most, so a garbled or hostile file is an error naming the line, not a RecursionError)."""
    if depth > MAX_DEPTH:
        raise tok.fail(f"joints nested more than {MAX_DEPTH} deep; not a skeleton this reader takes")
    if len(tree.names) >= MAX_JOINTS:
        raise tok.fail(f"more than {MAX_JOINTS} joints; not a skeleton this reader takes")
    name = tok.rest_of_line("a joint name")
    if not name:
        raise tok.fail("joint without a name")
    if len(name) > 200:
        raise tok.fail(f"joint name of {len(name)} characters ({name[:40]!r}...)")
    if name in tree.names:
        raise tok.fail(f"duplicate joint name {name[:60]!r}")
    tok.expect("{")
    tok.expect("OFFSET")
    offset = [tok.number(f"OFFSET of {name}") for _ in range(3)]
    chans: tuple[str, ...] = ()
    if (tok.peek() or "").upper() == "CHANNELS":
        tok.take("CHANNELS")
        count = tok.number(f"channel count of {name}")
        if count != int(count) or not 0 <= count <= 6:
            raise tok.fail(f"bad channel count {count:g} for {name}")
        chans = tuple(_channel(tok, name) for _ in range(int(count)))
        if len(set(chans)) != len(chans):
            raise tok.fail(f"repeated channel in {name}: {' '.join(chans)}")
    index = len(tree.names)
    tree.names.append(name)
    tree.parents.append(parent)
    tree.offsets.append(offset)
    tree.channels.append(chans)
    while True:
        head = tok.take(f"'}}' closing {name}")
        upper = head.upper()
        if upper == "}":
            return
        if upper == "JOINT":
            _parse_joint(tok, tree, index, depth + 1)
        elif upper == "END":
            tok.expect("Site")
            tok.expect("{")
            tok.expect("OFFSET")
            tree.end_sites[index] = np.array([tok.number(f"End Site OFFSET of {name}") for _ in range(3)])
            tok.expect("}")
        else:
            tok.pos -= 1
            raise tok.fail(f"expected JOINT, End Site or '}}' in {name}, found {head!r}")


def _channel(tok: _Tokens, joint: str) -> str:
    raw = tok.take(f"a channel name of {joint}")
    try:
        return _CHANNELS[raw.lower()]
    except KeyError:
        tok.pos -= 1
        raise tok.fail(f"unknown channel {raw!r} in {joint}") from None


def _parse_hierarchy(text: str, source: str) -> _Tree:
    tok = _Tokens(text, source)
    tok.expect("HIERARCHY")
    tree = _Tree()
    while tok.peek() is not None:
        tok.expect("ROOT")
        _parse_joint(tok, tree, -1)
    if not tree.names:
        raise MotionDataError(source, "hierarchy has no ROOT joint")
    return tree


def _header_value(rows: list[tuple[int, str]], index: int, pattern: re.Pattern[str], what: str, source: str) -> str:
    if index >= len(rows):
        raise MotionDataError(source, f"MOTION section ends before the {what} line")
    line, text = rows[index]
    match = pattern.match(text)
    if not match:
        raise MotionDataError(source, f"line {line}: expected '{what}: <value>', found {text.strip()[:40]!r}")
    return match.group(1)


def _parse_frames(rows: list[tuple[int, str]], n_frames: int, n_channels: int, source: str) -> np.ndarray:
    """(F, C) values from the non-blank data lines, given as (file line number, text)."""
    split = [(n, text.split()) for n, text in rows]
    for n, toks in split[:n_frames]:
        if len(toks) != n_channels:
            raise MotionDataError(source, f"line {n}: expected {n_channels} channel values, found {len(toks)}")
    if len(split) < n_frames:
        raise MotionDataError(source, f"truncated: header says {n_frames} frames, found {len(split)}")
    if len(split) > n_frames:
        line = split[n_frames][0]
        raise MotionDataError(source, f"line {line}: header says {n_frames} frames, found {len(split)} frame lines")
    try:
        values = np.array(list(chain.from_iterable(t for _, t in split)), dtype=np.float64)
    except ValueError:
        raise _bad_number(split, source) from None
    values = values.reshape(n_frames, n_channels)
    bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
    if bad.size:
        raise MotionDataError(source, f"line {split[bad[0]][0]}: non-finite channel value")
    return values


def _bad_number(rows: list[tuple[int, list[str]]], source: str) -> MotionDataError:
    for n, toks in rows:
        for tok in toks:
            try:
                float(tok)
            except ValueError:
                return MotionDataError(source, f"line {n}: {tok[:40]!r} is not a number")
    return MotionDataError(source, "unreadable frame values")


def read_bvh(path: str | os.PathLike[str]) -> BvhMotion:
    """Parse a BVH file of any hierarchy, channel layout, units and frame rate.

    Raises ``MotionDataError(path, reason)`` for a missing, empty, truncated or garbled file.
    """
    source = str(path)
    try:
        raw = Path(path).read_bytes()
    except OSError as err:
        raise MotionDataError(source, f"cannot read file ({err.strerror or err})") from None
    if not raw.strip():
        raise MotionDataError(source, "empty file")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise MotionDataError(source, f"not a text file (byte {err.start} is not UTF-8)") from None
    match = _MOTION.search(text)
    if match is None:
        raise MotionDataError(source, "no MOTION section")
    tree = _parse_hierarchy(text[: match.start()], source)
    first = text.count("\n", 0, match.start()) + 2  # file line of the line after MOTION
    lines = text[match.end() :].splitlines()[1:]  # [0] is the rest of the MOTION line
    rows = [(first + i, ln) for i, ln in enumerate(lines) if ln.strip()]
    frames_tok = _header_value(rows, 0, _FRAMES, "Frames", source)
    time_tok = _header_value(rows, 1, _FRAME_TIME, "Frame Time", source)
    n_frames, frame_time = _header_numbers(frames_tok, time_tok, source)
    n_channels = sum(len(c) for c in tree.channels)
    values = _parse_frames(rows[2:], n_frames, n_channels, source)
    return BvhMotion(
        source=source,
        names=tree.names,
        parents=tree.parents,
        offsets=np.asarray(tree.offsets, dtype=np.float64),
        channels=tree.channels,
        frame_time=frame_time,
        frames=values,
        end_sites=tree.end_sites,
    )


def _header_numbers(frames_tok: str, time_tok: str, source: str) -> tuple[int, float]:
    try:
        n_frames = int(frames_tok)
    except ValueError:
        raise MotionDataError(source, f"frame count {frames_tok!r} is not an integer") from None
    try:
        frame_time = float(time_tok)
    except ValueError:
        raise MotionDataError(source, f"frame time {time_tok!r} is not a number") from None
    if n_frames < 1:
        raise MotionDataError(source, f"header says {n_frames} frames; need at least 1")
    if not (np.isfinite(frame_time) and frame_time > 0):
        raise MotionDataError(source, f"frame time must be positive, got {time_tok}")
    return n_frames, frame_time


# --------------------------------------------------------------------------- writers


def write_bvh(
    path: str | os.PathLike[str],
    names: Sequence[str],
    parents: Sequence[int],
    offsets: np.ndarray,
    local_quats: np.ndarray,
    root_pos: np.ndarray,
    fps: float,
    order: str = "ZXY",
    end_sites: dict[int, np.ndarray] | None = None,
    translations: np.ndarray | None = None,
) -> Path:
    """Write a BVH: root with position + rotation channels, other joints rotation only.

    ``local_quats`` (F, J, 4) are (w, x, y, z) rotations relative to the parent; ``root_pos``
    (F, 3) is the root's position (it replaces the root OFFSET on reading). ``translations``
    (F, J, 3), for rigs whose joints also move in their parent (Bandai's Hips under a static
    root), gives every joint position channels, as MotionBuilder writes them. Leaves get an End
    Site (``end_sites[j]`` or half their own offset, so viewers draw a visible bone). The file
    appears atomically (temp file + rename), so readers never see half a file.
    """
    offsets, local_quats, root_pos = (np.asarray(a, dtype=np.float64) for a in (offsets, local_quats, root_pos))
    _check_writer_input(path, names, parents, offsets, local_quats, root_pos, fps, order)
    if translations is not None:
        translations = np.array(translations, dtype=np.float64)
        if translations.shape != local_quats.shape[:2] + (3,) or not np.isfinite(translations).all():
            want = local_quats.shape[:2] + (3,)
            raise MotionDataError(str(path), f"translations {translations.shape} must be finite, shape {want}")
        translations[:, parents.index(-1)] = root_pos
    children = _children(parents)
    dfs = _depth_first(children, parents.index(-1))
    angles = matrix_to_euler(quat_to_matrix(local_quats), order)  # (F, J, 3)
    lines = ["HIERARCHY"]
    _write_joint(lines, dfs[0], 0, names, offsets, children, order, end_sites or {}, translations is not None)
    lines += ["MOTION", f"Frames: {local_quats.shape[0]}", f"Frame Time: {1.0 / fps:.9g}"]
    if translations is None:
        columns = np.concatenate([root_pos[:, None, :], angles[:, dfs]], axis=1).reshape(len(root_pos), -1)
    else:
        columns = np.concatenate([translations[:, dfs], angles[:, dfs]], axis=2).reshape(len(root_pos), -1)
    lines += [" ".join(f"{v:.9g}" for v in row) for row in columns]
    atomic_write_text(path, "\n".join(lines) + "\n")
    return Path(path)


def _check_writer_input(
    path: str | os.PathLike[str],
    names: Sequence[str],
    parents: Sequence[int],
    offsets: np.ndarray,
    local_quats: np.ndarray,
    root_pos: np.ndarray,
    fps: float,
    order: str,
) -> None:
    _check_order(order)
    n = len(names)
    problems = []
    if len(parents) != n or offsets.shape != (n, 3):
        problems.append(f"{n} names, {len(parents)} parents, offsets {offsets.shape}")
    if list(parents).count(-1) != 1:
        problems.append("need exactly one root (parent -1)")
    if any(not -1 <= p < n or p == j for j, p in enumerate(parents)):
        problems.append("parent index out of range")
    if local_quats.ndim != 3 or local_quats.shape[1:] != (n, 4) or root_pos.shape != (local_quats.shape[0], 3):
        problems.append(f"local_quats {local_quats.shape} / root_pos {root_pos.shape} do not match {n} joints")
    if len(set(names)) != n or any(not s or s != s.strip() or "{" in s or "}" in s for s in names):
        problems.append("joint names must be unique, non-empty, without braces or outer spaces")
    if not fps > 0:
        problems.append(f"fps must be positive, got {fps}")
    if not problems and not (np.isfinite(local_quats).all() and np.isfinite(root_pos).all()):
        problems.append("non-finite rotation or position")
    if problems:
        raise MotionDataError(str(path), "; ".join(problems))


def _children(parents: Sequence[int]) -> list[list[int]]:
    children: list[list[int]] = [[] for _ in parents]
    for j, p in enumerate(parents):
        if p >= 0:
            children[p].append(j)
    return children


def _depth_first(children: list[list[int]], root: int) -> list[int]:
    order, stack = [], [root]
    while stack:
        j = stack.pop()
        order.append(j)
        stack.extend(reversed(children[j]))
    if len(order) != len(children):
        raise ValueError("parents do not form a single tree")
    return order


def _write_joint(
    lines: list[str],
    j: int,
    depth: int,
    names: Sequence[str],
    offsets: np.ndarray,
    children: list[list[int]],
    order: str,
    end_sites: dict[int, np.ndarray],
    all_positions: bool,
) -> None:
    pad = "  " * depth
    rot = " ".join(f"{a}rotation" for a in order)
    lines.append(f"{pad}{'ROOT' if depth == 0 else 'JOINT'} {names[j]}")
    lines.append(f"{pad}{{")
    lines.append(f"{pad}  OFFSET {_fmt3(offsets[j])}")
    moves = depth == 0 or all_positions
    lines.append(f"{pad}  CHANNELS 6 Xposition Yposition Zposition {rot}" if moves else f"{pad}  CHANNELS 3 {rot}")
    for child in children[j]:
        _write_joint(lines, child, depth + 1, names, offsets, children, order, end_sites, all_positions)
    if not children[j]:
        tip = end_sites.get(j, 0.5 * offsets[j])
        lines += [f"{pad}  End Site", f"{pad}  {{", f"{pad}    OFFSET {_fmt3(np.asarray(tip))}", f"{pad}  }}"]
    lines.append(f"{pad}}}")


def _fmt3(v: np.ndarray) -> str:
    return " ".join(f"{float(x):.9g}" for x in v)


# --------------------------------------------------------------------------- t2m joints -> BVH


def joints_to_bvh(
    path: str | os.PathLike[str], joints: np.ndarray, fps: float = 20.0, skeleton: Skeleton = T2M
) -> float:
    """Write joint positions (T, J, 3) in metres as a BVH (metres, Y up) with the skeleton's names.

    Offsets are the clip's own bone lengths along the skeleton's rest directions; each joint's
    rotation maps its rest bone onto the clip's bone (HumanML3D's IK gives the same bone
    rotation: the shortest arc from rest to actual direction). Joints with several children
    (pelvis, spine3) cannot follow fixed rest directions, so their children keep the clip's own
    frame-0 layout and the joint takes the best-fit rotation. Returns the largest position error
    in metres of the written skeleton against ``joints`` (0 up to rounding for rigid clips).
    """
    joints = np.asarray(joints, dtype=np.float64)
    if joints.ndim != 3 or joints.shape[1:] != (skeleton.n_joints, 3) or len(joints) < 1:
        raise MotionDataError(str(path), f"joints must be (T, {skeleton.n_joints}, 3), got {joints.shape}")
    if not np.isfinite(joints).all():
        raise MotionDataError(str(path), "joints contain non-finite values")
    parents = skeleton.parents
    offsets = _rest_offsets(joints, skeleton)
    glob = _bone_rotations(joints, parents, offsets)
    local = glob.copy()
    for j, p in enumerate(parents):
        if p >= 0:
            local[:, j] = np.swapaxes(glob[:, p], -1, -2) @ glob[:, j]
    write_bvh(path, skeleton.joint_names, parents, offsets, matrix_to_quat(local), joints[:, 0], fps)
    trans = np.broadcast_to(offsets, joints.shape).copy()
    trans[:, 0] = joints[:, 0]
    _, pos = forward_kinematics(parents, local, trans)
    return float(np.abs(pos - joints).max())


def _rest_offsets(joints: np.ndarray, skeleton: Skeleton) -> np.ndarray:
    """(J, 3) rest offsets: clip bone length along the rest direction (see ``joints_to_bvh``)."""
    parents = skeleton.parents
    children = _children(parents)
    facing = _facing_rotation(joints[0], skeleton)
    offsets = np.zeros((skeleton.n_joints, 3))
    for j, p in enumerate(parents):
        if p < 0:
            continue
        bone = joints[:, j] - joints[:, p]
        length = float(np.median(np.linalg.norm(bone, axis=-1)))
        rest = np.asarray(skeleton.raw_offsets[j], dtype=np.float64)
        if len(children[p]) > 1 or not rest.any():
            rest = facing @ bone[0]
        offsets[j] = _unit(rest) * length
    return offsets


def _facing_rotation(pose: np.ndarray, skeleton: Skeleton) -> np.ndarray:
    """Rotation about Y that turns the pose to face +Z (HumanML3D's hips + shoulders rule)."""
    r_hip, l_hip, r_sdr, l_sdr = skeleton.face_joints
    across = pose[r_hip] - pose[l_hip] + pose[r_sdr] - pose[l_sdr]
    forward = np.cross([0.0, 1.0, 0.0], across)
    angle = np.arctan2(forward[0], forward[2])  # heading of forward, measured from +Z toward +X
    return axis_rotation("Y", np.array(-angle))


def _bone_rotations(joints: np.ndarray, parents: Sequence[int], offsets: np.ndarray) -> np.ndarray:
    """(T, J, 3, 3) world rotation per joint carrying its children's rest offsets onto the clip."""
    children = _children(parents)
    glob = np.broadcast_to(np.eye(3), (len(joints), len(parents), 3, 3)).copy()
    for j in range(len(parents)):
        kids = children[j]
        if not kids:
            glob[:, j] = glob[:, parents[j]] if parents[j] >= 0 else glob[:, j]
            continue
        actual = np.stack([joints[:, c] - joints[:, j] for c in kids], axis=1)  # (T, K, 3)
        rest = np.stack([offsets[c] for c in kids], axis=0)  # (K, 3)
        glob[:, j] = _shortest_arc(rest[0], actual[:, 0]) if len(kids) == 1 else _best_fit(rest, actual)
    return glob


def _unit(v: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.maximum(norm, 1e-12)


def _shortest_arc(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(T, 3, 3) smallest rotation taking direction ``u`` (3,) onto each direction ``v`` (T, 3)."""
    a = np.broadcast_to(_unit(u), v.shape)
    b = _unit(v)
    axis = np.cross(a, b)
    cos = np.einsum("ta,ta->t", a, b)
    opposite = cos < -1 + 1e-9
    if opposite.any():  # any axis perpendicular to u works for a half turn
        helper = np.array([1.0, 0.0, 0.0]) if abs(a[0, 0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        axis[opposite] = 2 * _unit(np.cross(a[opposite], helper))  # scaled so w = 0 after normalising
    quat = np.concatenate([(1 + cos)[:, None], axis], axis=-1)
    return quat_to_matrix(quat)


def _best_fit(rest: np.ndarray, actual: np.ndarray) -> np.ndarray:
    """(T, 3, 3) rotation best mapping rest directions (K, 3) onto actual ones (T, K, 3) (Kabsch)."""
    cov = np.einsum("ka,tkb->tba", _unit(rest), _unit(actual))
    u, _, vt = np.linalg.svd(cov)
    fix = np.sign(np.linalg.det(u @ vt))
    u[:, :, -1] *= fix[:, None]
    return u @ vt
