"""HumanML3D motion features: extraction from joints, recovery to joints, mirroring, Mean/Std.

Extraction reproduces HumanML3D's ``process_file`` with its ``common/skeleton.py`` IK, frame-0 root reset included,
so features computed here line up with the released ``new_joint_vecs``. Per frame: ``[root_rot_vel 1 | root_lin_vel
2 (xz) | root_y 1 | ric 3(J-1) | rot 6(J-1) | local_vel 3J | feet 4]``. A reference quirk is kept on purpose: the root
rotation velocity is ``arcsin`` of the per-frame yaw quaternion's y, which flips sign when the smoothed facing
crosses straight backwards (Z-), so such a clip does not round-trip exactly; the dataset has the same property.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import numpy as np
import torch
from torch import Tensor

from motionaug.augment.io import atomic_save_npy
from motionaug.augment.motion.kinematics import (
    forward_kinematics_cont6d,
    inverse_kinematics,
    root_facing_quat,
    t2m_target_offsets,
    uniform_skeleton,
)
from motionaug.augment.motion.rotations import qinv, qmul, qrot, quat_to_cont6d
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import T2M, Skeleton

ArrayT = TypeVar("ArrayT", np.ndarray, Tensor)

FEATURE_BLOCKS = ("root_rot_vel", "root_lin_vel", "root_y", "ric", "rot", "local_vel", "feet")
DEFAULT_FEET_THRESHOLD = 0.002  # squared metres per frame, as the reference's ``feet_thre``


def feature_slices(skeleton: Skeleton) -> dict[str, slice]:
    """Channel ranges of each feature block for ``skeleton`` (keys: ``FEATURE_BLOCKS``)."""
    j = skeleton.n_joints
    widths = (1, 2, 1, 3 * (j - 1), 6 * (j - 1), 3 * j, 4)
    slices: dict[str, slice] = {}
    start = 0
    for name, width in zip(FEATURE_BLOCKS, widths):
        slices[name] = slice(start, start + width)
        start += width
    return slices


def _feature_dim(joints_num: int) -> int:
    return 4 + 9 * (joints_num - 1) + 3 * joints_num + 4


# ---- extraction ----------------------------------------------------------------------------


@dataclass(frozen=True)
class Extraction:
    """Features (T-1, D) float32 and the canonicalised global joints (T, J, 3) float64 they encode.

    ``recover_from_ric(features)`` reproduces ``joints[:-1]``.
    """

    features: np.ndarray
    joints: np.ndarray


def _check_joints(joints: np.ndarray, skeleton: Skeleton, source: str) -> np.ndarray:
    arr = np.asarray(joints)
    if arr.ndim != 3 or arr.shape[1:] != (skeleton.n_joints, 3):
        raise MotionDataError(source, f"joints must be (T, {skeleton.n_joints}, 3), got shape {arr.shape}")
    if arr.shape[0] < 2:
        raise MotionDataError(source, f"need at least 2 frames to extract features, got {arr.shape[0]}")
    if not np.issubdtype(arr.dtype, np.number):
        raise MotionDataError(source, f"joints must be numeric, got dtype {arr.dtype}")
    arr = arr.astype(np.float64)
    if not np.isfinite(arr).all():
        raise MotionDataError(source, "joints contain NaN or infinite values")
    return arr


def _resolve_offsets(skeleton: Skeleton, offsets: np.ndarray | Tensor | None) -> Tensor:
    if offsets is None:
        if skeleton.name != T2M.name:
            raise ValueError(f"skeleton {skeleton.name}: pass target_offsets (only t2m has shipped defaults)")
        offsets = t2m_target_offsets()
    off = torch.as_tensor(np.asarray(offsets, dtype=np.float64)) if not isinstance(offsets, Tensor) else offsets
    if tuple(off.shape) != (skeleton.n_joints, 3):
        raise ValueError(
            f"skeleton {skeleton.name}: target offsets must be ({skeleton.n_joints}, 3), got {tuple(off.shape)}"
        )
    return off.to(torch.float64)


def _canonicalise(skeleton: Skeleton, pos: Tensor) -> Tensor:
    """Put on the floor, move frame 0's root to the XZ origin, and turn frame 0 to face Z+."""
    floor = pos[..., 1].min()
    pos = pos - torch.stack([torch.zeros_like(floor), floor, torch.zeros_like(floor)])
    root0 = pos[0, 0]
    pos = pos - torch.stack([root0[0], torch.zeros_like(root0[1]), root0[2]])
    facing = root_facing_quat(skeleton, pos[0])
    return qrot(facing.expand(pos.shape[:-1] + (4,)), pos)


def _foot_contacts(skeleton: Skeleton, pos: Tensor, threshold: float) -> Tensor:
    """(T-1, 4) contacts [left ankle, left toe, right ankle, right toe]: squared step below threshold."""
    feet = list(skeleton.feet_left) + list(skeleton.feet_right)
    step = ((pos[1:, feet] - pos[:-1, feet]) ** 2).sum(-1)
    return (step < threshold).to(pos.dtype)


def extract_features_and_joints(
    joints: np.ndarray,
    skeleton: Skeleton = T2M,
    target_offsets: np.ndarray | Tensor | None = None,
    feet_threshold: float = DEFAULT_FEET_THRESHOLD,
    source: str = "joints",
) -> Extraction:
    """HumanML3D's ``process_file`` on joint positions (T, J, 3) in metres, Y up.

    ``target_offsets`` defaults to the T2M target skeleton; ``source`` names the clip in errors.
    """
    pos = torch.as_tensor(_check_joints(joints, skeleton, source))
    tgt = _resolve_offsets(skeleton, target_offsets)
    pos = _canonicalise(skeleton, uniform_skeleton(skeleton, pos, tgt))
    n_frames, n_joints = pos.shape[0], pos.shape[1]

    quats = inverse_kinematics(skeleton, pos, smooth_forward=True)  # (T, J, 4)
    r_rot = quats[:, 0]
    root_step = qrot(r_rot[1:], pos[1:, 0] - pos[:-1, 0])
    r_velocity = qmul(r_rot[1:], qinv(r_rot[:-1]))
    # Deviation from the reference: take the short way round (w >= 0) before asin. The reference's
    # asin(y) flips the sign of one frame's turn whenever the facing crosses 180 degrees, so such
    # clips did not decode back to their own trajectory; every other clip is unchanged.
    r_velocity = torch.where(r_velocity[:, :1] < 0, -r_velocity, r_velocity)

    horizontal = torch.tensor([1.0, 0.0, 1.0], dtype=pos.dtype)
    local = qrot(r_rot[:, None].expand(-1, n_joints, -1), pos - pos[:, :1] * horizontal)  # ric, (T, J, 3)
    local_vel = qrot(r_rot[:-1, None].expand(-1, n_joints, -1), pos[1:] - pos[:-1])

    features = torch.cat(
        [
            torch.asin(r_velocity[:, 2:3].clamp(-1.0, 1.0)),
            root_step[:, [0, 2]],
            local[:-1, 0, 1:2],
            local[:-1, 1:].reshape(n_frames - 1, -1),
            quat_to_cont6d(quats[:-1, 1:]).reshape(n_frames - 1, -1),
            local_vel.reshape(n_frames - 1, -1),
            _foot_contacts(skeleton, pos, feet_threshold),
        ],
        dim=-1,
    )
    if not torch.isfinite(features).all():
        raise MotionDataError(source, "degenerate pose (zero-length bone or no facing direction) gives NaN features")
    return Extraction(features=features.numpy().astype(np.float32), joints=pos.numpy())


def extract_features(
    joints: np.ndarray,
    skeleton: Skeleton = T2M,
    target_offsets: np.ndarray | Tensor | None = None,
    feet_threshold: float = DEFAULT_FEET_THRESHOLD,
    source: str = "joints",
) -> np.ndarray:
    """Features (T-1, D) float32 of joint positions (T, J, 3); see ``extract_features_and_joints``."""
    return extract_features_and_joints(joints, skeleton, target_offsets, feet_threshold, source).features


# ---- recovery (torch, any leading dims) ----------------------------------------------------


def _check_features(data: Tensor, joints_num: int) -> None:
    expected = _feature_dim(joints_num)
    if data.dim() < 2 or data.shape[-1] != expected:
        raise MotionDataError(
            "features", f"expected (..., T, {expected}) for {joints_num} joints, got {tuple(data.shape)}"
        )


def recover_root_rot_pos(data: Tensor) -> tuple[Tensor, Tensor]:
    """Root yaw quaternions (..., T, 4) and root positions (..., T, 3) by integrating the velocities."""
    rot_vel = data[..., 0]
    angle = torch.cumsum(torch.cat([torch.zeros_like(rot_vel[..., :1]), rot_vel[..., :-1]], dim=-1), dim=-1)
    zero = torch.zeros_like(angle)
    r_rot = torch.stack([torch.cos(angle), zero, torch.sin(angle), zero], dim=-1)
    step = torch.stack([data[..., :-1, 1], torch.zeros_like(data[..., :-1, 1]), data[..., :-1, 2]], dim=-1)
    step = torch.cat([torch.zeros_like(step[..., :1, :]), step], dim=-2)
    travelled = torch.cumsum(qrot(qinv(r_rot), step), dim=-2)
    r_pos = torch.stack([travelled[..., 0], data[..., 3], travelled[..., 2]], dim=-1)
    return r_rot, r_pos


def recover_from_ric(data: Tensor, joints_num: int) -> Tensor:
    """Global joints (..., T, J, 3) from the root-relative positions block (the dataset's ``new_joints``)."""
    _check_features(data, joints_num)
    r_rot, r_pos = recover_root_rot_pos(data)
    ric = data[..., 4 : 4 + (joints_num - 1) * 3].reshape(data.shape[:-1] + (joints_num - 1, 3))
    world = qrot(qinv(r_rot)[..., None, :], ric)
    world = world + torch.stack([r_pos[..., 0], torch.zeros_like(r_pos[..., 1]), r_pos[..., 2]], dim=-1)[..., None, :]
    return torch.cat([r_pos[..., None, :], world], dim=-2)


def features_to_joints(
    features: ArrayT,
    skeleton: Skeleton = T2M,
    mean: np.ndarray | None = None,
    std: np.ndarray | None = None,
    *,
    source: str = "features",
) -> ArrayT:
    """``(..., T, D)`` features -> ``(..., T, J, 3)`` joints via ``recover_from_ric``, as the input's type.

    Normalised features are denormalised first when ``mean`` and ``std`` are given. The one conversion every
    consumer (evaluators, previews, BVH export, training) uses, so joints mean the same thing everywhere.
    """
    feats = torch.as_tensor(features, dtype=torch.float32)
    if feats.ndim < 2 or feats.shape[-1] != skeleton.feature_dim:
        raise MotionDataError(
            source,
            f"width {feats.shape[-1] if feats.ndim else 0} != {skeleton.feature_dim} for skeleton {skeleton.name}"
            f" (expected (T, {skeleton.feature_dim}) features, got {tuple(feats.shape)})",
        )
    if feats.shape[-2] < 1:
        raise MotionDataError(source, "has no frames")
    if not bool(torch.isfinite(feats).all()):
        raise MotionDataError(source, "features contain NaN or inf")
    if (mean is None) != (std is None):
        raise MotionDataError(source, "give both mean and std to denormalise, or neither")
    if mean is not None and std is not None:
        feats = feats * torch.as_tensor(std, dtype=torch.float32) + torch.as_tensor(mean, dtype=torch.float32)
    with torch.no_grad():
        joints = recover_from_ric(feats, skeleton.n_joints)
    return joints if isinstance(features, Tensor) else joints.numpy()  # type: ignore[return-value]


def recover_from_rot(
    data: Tensor,
    joints_num: int,
    skeleton: Skeleton = T2M,
    offsets: np.ndarray | Tensor | None = None,
) -> Tensor:
    """Global joints (..., T, J, 3) by forward kinematics of the 6D rotation block on ``offsets``."""
    _check_features(data, joints_num)
    if skeleton.n_joints != joints_num:
        raise ValueError(f"skeleton {skeleton.name} has {skeleton.n_joints} joints, not {joints_num}")
    r_rot, r_pos = recover_root_rot_pos(data)
    start = 4 + (joints_num - 1) * 3
    rot6d = data[..., start : start + (joints_num - 1) * 6].reshape(data.shape[:-1] + (joints_num - 1, 6))
    cont6d = torch.cat([quat_to_cont6d(r_rot)[..., None, :], rot6d], dim=-2)
    off = _resolve_offsets(skeleton, offsets).to(dtype=data.dtype, device=data.device)
    return forward_kinematics_cont6d(skeleton, off, cont6d, r_pos)


# ---- mirroring -----------------------------------------------------------------------------


def _mirror_perm(skeleton: Skeleton) -> list[int]:
    perm = skeleton.mirror_permutation
    if perm[0] != 0:
        raise ValueError(f"skeleton {skeleton.name}: mirroring must keep the root in place")
    return perm


def _check_mirror_symmetric(skeleton: Skeleton, perm: list[int]) -> None:
    """Channel-wise feature mirroring is exact only if the rig maps onto itself under x -> -x."""
    parents = skeleton.parents
    for i, p in enumerate(perm):
        x, y, z = skeleton.raw_offsets[i]
        if tuple(skeleton.raw_offsets[p]) != (-x, y, z) or (i and parents[p] != perm[parents[i]]):
            raise ValueError(f"skeleton {skeleton.name}: joint {skeleton.joint_names[i]} has no mirror image")
    if [perm[j] for j in skeleton.feet_left] != list(skeleton.feet_right):
        raise ValueError(f"skeleton {skeleton.name}: mirror_pairs do not swap feet_left and feet_right")


def _as_like(values: np.ndarray, ref: ArrayT) -> ArrayT:
    if isinstance(ref, Tensor):
        return torch.as_tensor(values, dtype=ref.dtype, device=ref.device)
    return values.astype(ref.dtype, copy=False)


def mirror_joints(joints: ArrayT, skeleton: Skeleton = T2M) -> ArrayT:
    """Reflect x -> -x and swap left/right joints (..., J, 3), as HumanML3D's ``M`` clips."""
    perm = _mirror_perm(skeleton)
    if joints.shape[-2:] != (skeleton.n_joints, 3):
        raise MotionDataError("joints", f"expected (..., {skeleton.n_joints}, 3), got {tuple(joints.shape)}")
    return joints[..., perm, :] * _as_like(np.array([-1.0, 1.0, 1.0]), joints)


def _feature_mirror_map(skeleton: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    """Channel index and sign per output channel so that ``mirrored = f[..., index] * sign``."""
    perm = _mirror_perm(skeleton)
    _check_mirror_symmetric(skeleton, perm)
    sl = feature_slices(skeleton)
    index = np.arange(_feature_dim(skeleton.n_joints))
    sign = np.ones(len(index))
    sign[sl["root_rot_vel"]] = -1.0  # yaw reverses
    sign[sl["root_lin_vel"].start] = -1.0  # x velocity
    non_root = [p - 1 for p in perm[1:]]

    def per_joint(block: slice, joints: list[int], signs: list[float]) -> None:
        width = len(signs)
        src = np.arange(block.start, block.stop).reshape(-1, width)[joints].reshape(-1)
        index[block] = src
        sign[block] = np.tile(signs, len(joints))

    per_joint(sl["ric"], non_root, [-1.0, 1.0, 1.0])
    # R' = M R M: first column becomes (c0x, -c0y, -c0z), second (-c1x, c1y, c1z)
    per_joint(sl["rot"], non_root, [1.0, -1.0, -1.0, -1.0, 1.0, 1.0])
    per_joint(sl["local_vel"], perm, [-1.0, 1.0, 1.0])
    feet = sl["feet"].start
    index[sl["feet"]] = [feet + 2, feet + 3, feet, feet + 1]
    return index, sign


def mirror_features(features: ArrayT, skeleton: Skeleton = T2M) -> ArrayT:
    """Features of the mirrored motion, channel-wise.

    Exact in the sense ``recover_from_ric(mirror_features(f)) == mirror_joints(recover_from_ric(f))``,
    and equal to re-extracting mirrored joints when the target rig's two sides match. The T2M target
    rig's sides differ by up to 9 mm per bone, and re-extraction retargets the swapped bones onto it;
    HumanML3D's ``M`` clips were made that way, from mirrored raw joints (``extract_features(mirror_joints(raw))``).
    """
    if features.shape[-1] != skeleton.feature_dim:
        raise MotionDataError("features", f"expected last dim {skeleton.feature_dim}, got {tuple(features.shape)}")
    index, sign = _feature_mirror_map(skeleton)
    if isinstance(features, Tensor):
        return features[..., torch.as_tensor(index, device=features.device)] * _as_like(sign, features)
    return features[..., index] * _as_like(sign, features)


# ---- normalisation -------------------------------------------------------------------------

MEAN_FILE = "Mean.npy"
STD_FILE = "Std.npy"


@dataclass(frozen=True)
class Normalizer:
    """Per-channel z-scoring with the dataset's Mean/Std (float32, shape (D,))."""

    mean: np.ndarray
    std: np.ndarray

    def __post_init__(self) -> None:
        mean = np.asarray(self.mean, dtype=np.float32)
        std = np.asarray(self.std, dtype=np.float32)
        if mean.ndim != 1 or mean.shape != std.shape:
            raise MotionDataError("Mean/Std", f"need two equal 1-D arrays, got {mean.shape} and {std.shape}")
        if not (np.isfinite(mean).all() and np.isfinite(std).all()) or (std <= 0).any():
            raise MotionDataError("Mean/Std", "values must be finite and std strictly positive")
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "std", std)

    @property
    def dim(self) -> int:
        return int(self.mean.shape[0])

    def _stats(self, x: ArrayT) -> tuple[ArrayT, ArrayT]:
        if x.shape[-1] != self.dim:
            raise MotionDataError("features", f"last dim {x.shape[-1]} does not match Mean/Std dim {self.dim}")
        return _as_like(self.mean, x), _as_like(self.std, x)

    def normalize(self, x: ArrayT) -> ArrayT:
        mean, std = self._stats(x)
        return (x - mean) / std

    def denormalize(self, x: ArrayT) -> ArrayT:
        mean, std = self._stats(x)
        return x * std + mean

    @classmethod
    def load(cls, directory: str | Path) -> Normalizer:
        """Read ``Mean.npy`` and ``Std.npy`` from a HumanML3D-style folder."""
        folder = Path(directory)
        arrays = []
        for name in (MEAN_FILE, STD_FILE):
            path = folder / name
            if not path.is_file():
                raise MotionDataError(str(path), "file not found")
            try:
                arrays.append(np.load(path, allow_pickle=False))
            except (ValueError, OSError) as err:
                raise MotionDataError(str(path), f"not a readable .npy array ({err})") from None
        return cls(arrays[0], arrays[1])

    def save(self, directory: str | Path) -> None:
        folder = Path(directory)
        atomic_save_npy(folder / MEAN_FILE, self.mean)
        atomic_save_npy(folder / STD_FILE, self.std)


def compute_mean_std(features: Iterable[np.ndarray], skeleton: Skeleton = T2M) -> Normalizer:
    """Mean and Std over all frames of all clips, as HumanML3D's ``cal_mean_variance``, in one streaming pass.

    Each block's std is replaced by that block's average std (the reference divides by 1.0),
    so channels within a block keep their relative scale. Clips with NaN are an error here,
    where the reference silently skipped them. Memory is O(one clip): running sums in float64,
    each clip centred on the first clip's mean to keep the variance numerically stable.
    """
    count, shift = 0, None
    total = total_sq = np.zeros(skeleton.feature_dim)
    for i, clip in enumerate(features):
        arr = np.asarray(clip, dtype=np.float64)
        if arr.ndim != 2 or arr.shape[1] != skeleton.feature_dim:
            raise MotionDataError(f"clip {i}", f"expected (T, {skeleton.feature_dim}) features, got {arr.shape}")
        if not np.isfinite(arr).all():
            raise MotionDataError(f"clip {i}", "features contain NaN or infinite values")
        if len(arr) == 0:
            continue
        shift = arr.mean(axis=0) if shift is None else shift
        centred = arr - shift
        total, total_sq, count = total + centred.sum(axis=0), total_sq + (centred**2).sum(axis=0), count + len(arr)
    if count == 0 or shift is None:
        raise MotionDataError("features", "no clips to compute Mean/Std from")
    mean_c = total / count
    std = np.sqrt(np.maximum(total_sq / count - mean_c**2, 0.0))
    mean = mean_c + shift
    for name, block in feature_slices(skeleton).items():
        std[block] = std[block].mean()
        if not std[block.start] > 0:
            raise MotionDataError("features", f"block {name} is constant over all {count} frames (zero std)")
    return Normalizer(mean.astype(np.float32), std.astype(np.float32))
