"""Forward/inverse kinematics on a ``Skeleton``, exactly as HumanML3D's ``common/skeleton.py``.

Rotations are "chain-wise" as in the reference: every chain's first bone is expressed relative to
the root rotation (not to the chain's parent joint), and each further bone relative to the previous
one in the chain. IK and FK share that convention, so ``forward_kinematics(inverse_kinematics(j))``
reproduces ``j`` when the offsets' bone lengths match. Torch throughout; numpy in, numpy out where
the feature extraction needs it (float64).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from functools import cache
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from motionaug.augment.motion.rotations import cont6d_to_matrix, qbetween, qinv, qmul, qrot
from motionaug.schemas.skeleton import Skeleton

DATA_DIR = Path(__file__).resolve().parent
T2M_OFFSETS_FILE = DATA_DIR / "t2m_target_offsets.json"
FORWARD_SMOOTH_SIGMA = 20.0  # frames; the reference's ``gaussian_filter1d(forward, 20)``
_UP = (0.0, 1.0, 0.0)
_FACING = (0.0, 0.0, 1.0)


def _as_tensor(x: np.ndarray | Tensor) -> Tensor:
    """Numpy becomes float64 torch (the precise path); tensors pass through unchanged."""
    return x if isinstance(x, Tensor) else torch.as_tensor(np.asarray(x, dtype=np.float64))


def _like(x: Tensor, ref: Tensor) -> Tensor:
    return x.to(dtype=ref.dtype, device=ref.device)


def _raw_offsets(skeleton: Skeleton, ref: Tensor) -> Tensor:
    return torch.tensor(skeleton.raw_offsets, dtype=ref.dtype, device=ref.device)


def target_offsets(skeleton: Skeleton, joints_frame0: np.ndarray | Tensor) -> Tensor:
    """Rest offsets: each raw unit direction times that bone's length in ``joints_frame0`` (J, 3).

    Mirrors the reference's ``get_offsets_joints``; the root's offset is its raw (zero) offset.
    """
    joints = _as_tensor(joints_frame0)
    if joints.shape != (skeleton.n_joints, 3):
        raise ValueError(f"joints_frame0 must be ({skeleton.n_joints}, 3), got {tuple(joints.shape)}")
    raw = _raw_offsets(skeleton, joints)
    parents = skeleton.parents
    rows = [raw[0]]
    for i in range(1, skeleton.n_joints):
        rows.append((joints[i] - joints[parents[i]]).norm() * raw[i])
    return torch.stack(rows)


@cache
def _t2m_offsets_list() -> tuple[tuple[float, float, float], ...]:
    payload = json.loads(T2M_OFFSETS_FILE.read_text())
    return tuple(tuple(float(v) for v in row) for row in payload["offsets"])  # type: ignore[misc]


def t2m_target_offsets() -> np.ndarray:
    """The T2M target skeleton's offsets (22, 3), float64, derived from HumanML3D clip 000021 frame 0."""
    return np.array(_t2m_offsets_list(), dtype=np.float64)


def _walk_chains(
    skeleton: Skeleton,
    root_rot: Tensor,
    local_at: Callable[[int], Tensor],
    offsets: Tensor,
    root_pos: Tensor,
    compose: Callable[[Tensor, Tensor], Tensor],
    apply: Callable[[Tensor, Tensor], Tensor],
) -> Tensor:
    """Shared chain walk for quaternion and matrix FK; builds a list, so it stays autograd-friendly."""
    joints: list[Tensor | None] = [None] * skeleton.n_joints
    joints[0] = root_pos
    for chain in skeleton.kinematic_chain:
        rot = root_rot
        for parent, child in zip(chain[:-1], chain[1:]):
            rot = compose(rot, local_at(child))
            parent_pos = joints[parent]
            assert parent_pos is not None  # chains are validated by Skeleton to start at reached joints
            joints[child] = apply(rot, offsets[..., child, :]) + parent_pos
    return torch.stack([j for j in joints if j is not None], dim=-2)


def forward_kinematics(
    skeleton: Skeleton,
    offsets: np.ndarray | Tensor,
    local_quats: Tensor,
    root_pos: Tensor,
) -> Tensor:
    """Joint positions (..., T, J, 3) from chain-wise local quaternions (..., T, J, 4) and root positions (..., T, 3).

    ``local_quats[..., 0, :]`` is the root's global rotation; offsets are (J, 3) rest offsets.
    """
    if local_quats.shape[-2:] != (skeleton.n_joints, 4):
        raise ValueError(f"local_quats must end in ({skeleton.n_joints}, 4), got {tuple(local_quats.shape)}")
    offs = _like(_as_tensor(offsets), local_quats).expand(local_quats.shape[:-1] + (3,))
    return _walk_chains(skeleton, local_quats[..., 0, :], lambda j: local_quats[..., j, :], offs, root_pos, qmul, qrot)


def forward_kinematics_cont6d(
    skeleton: Skeleton,
    offsets: np.ndarray | Tensor,
    local_cont6d: Tensor,
    root_pos: Tensor,
) -> Tensor:
    """As ``forward_kinematics`` but with continuous-6D rotations (..., T, J, 6), composed as matrices."""
    if local_cont6d.shape[-2:] != (skeleton.n_joints, 6):
        raise ValueError(f"local_cont6d must end in ({skeleton.n_joints}, 6), got {tuple(local_cont6d.shape)}")
    mats = cont6d_to_matrix(local_cont6d)  # (..., T, J, 3, 3)
    offs = _like(_as_tensor(offsets), local_cont6d).expand(local_cont6d.shape[:-1] + (3,))

    def apply(m: Tensor, v: Tensor) -> Tensor:
        return (m @ v.unsqueeze(-1)).squeeze(-1)

    return _walk_chains(skeleton, mats[..., 0, :, :], lambda j: mats[..., j, :, :], offs, root_pos, torch.matmul, apply)


def gaussian_smooth_time(x: Tensor, sigma: float, time_dim: int) -> Tensor:
    """``scipy.ndimage.gaussian_filter1d(x, sigma, mode='nearest', truncate=4)`` along ``time_dim``."""
    radius = int(4.0 * sigma + 0.5)
    taps = torch.arange(-radius, radius + 1, dtype=x.dtype, device=x.device)
    weights = torch.exp(-0.5 * (taps / sigma) ** 2)
    weights = weights / weights.sum()
    x = x.movedim(time_dim, -1)
    n = x.shape[-1]
    index = (torch.arange(n, device=x.device)[:, None] + torch.arange(-radius, radius + 1, device=x.device)).clamp(
        0, n - 1
    )
    windows = x[..., index]  # (..., n, 2r+1): edge values repeat, as mode='nearest'
    return (windows * weights).sum(-1).movedim(-1, time_dim)


def _facing(joints: Tensor, hip_across: tuple[int, int], shoulder_across: tuple[int, int]) -> Tensor:
    """Facing direction up x across, across = unit(hip vector + shoulder vector), each ``joints[b] - joints[a]``.

    Not normalised: the reference smooths this raw cross product before normalising.
    """
    (h0, h1), (s0, s1) = hip_across, shoulder_across
    across = (joints[..., h1, :] - joints[..., h0, :]) + (joints[..., s1, :] - joints[..., s0, :])
    across = across / across.norm(dim=-1, keepdim=True)
    return torch.linalg.cross(_like(torch.tensor(_UP), joints).expand_as(across), across, dim=-1)


def _to_facing_z(forward: Tensor) -> Tensor:
    forward = forward / forward.norm(dim=-1, keepdim=True)
    return qbetween(forward, _like(torch.tensor(_FACING), forward).expand_as(forward))


def _ik_forward(skeleton: Skeleton, joints: Tensor, smooth: bool) -> Tensor:
    """Facing direction per frame as the reference's IK computes it (see ``inverse_kinematics``)."""
    r_hip, l_hip, r_sdr, l_sdr = skeleton.face_joints
    # The reference's IK unpacks face_joints as (l_hip, r_hip, sdr_r, sdr_l), so its hip term is
    # the opposite of process_file's; reproduced because the dataset's features depend on it.
    forward = _facing(joints, (r_hip, l_hip), (l_sdr, r_sdr))
    if smooth:
        forward = gaussian_smooth_time(forward, FORWARD_SMOOTH_SIGMA, time_dim=-2)
    return forward


def inverse_kinematics(
    skeleton: Skeleton,
    joints: np.ndarray | Tensor,
    smooth_forward: bool = False,
) -> Tensor:
    """Chain-wise local quaternions (..., T, J, 4) from joint positions (..., T, J, 3).

    As HumanML3D's ``inverse_kinematics_np``: the root rotation turns the (optionally Gaussian
    smoothed, sigma 20 frames) facing direction to Z+, frame 0's root rotation is then reset to
    identity, and each bone's rotation is the shortest arc from its raw offset to its direction.
    """
    pos = _as_tensor(joints)
    if pos.dim() < 3 or pos.shape[-2:] != (skeleton.n_joints, 3):
        raise ValueError(f"joints must be (..., T, {skeleton.n_joints}, 3), got {tuple(pos.shape)}")
    forward = _ik_forward(skeleton, pos, smooth_forward)
    root = _to_facing_z(forward)
    identity = _like(torch.tensor([1.0, 0.0, 0.0, 0.0]), pos).expand_as(root[..., :1, :])
    root = torch.cat([identity, root[..., 1:, :]], dim=-2)
    raw = _raw_offsets(skeleton, pos)
    local: list[Tensor | None] = [None] * skeleton.n_joints
    local[0] = root
    for chain in skeleton.kinematic_chain:
        rot = root
        for parent, child in zip(chain[:-1], chain[1:]):
            bone = pos[..., child, :] - pos[..., parent, :]
            bone = bone / bone.norm(dim=-1, keepdim=True)
            arc = qbetween(raw[child].expand_as(bone), bone)
            loc = qmul(qinv(rot), arc)
            local[child] = loc
            rot = qmul(rot, loc)
    return torch.stack([q for q in local if q is not None], dim=-2)


def leg_length(skeleton: Skeleton, offsets: Tensor) -> Tensor:
    """The reference's scale measure: largest |component| of the two ``leg_joints`` offsets, summed."""
    a, b = skeleton.leg_joints
    return offsets[a].abs().max() + offsets[b].abs().max()


def uniform_skeleton(
    skeleton: Skeleton,
    joints: np.ndarray | Tensor,
    target: np.ndarray | Tensor,
) -> Tensor:
    """Retarget a clip (T, J, 3) to the target offsets: scale the root path by leg length, IK, then FK."""
    pos = _as_tensor(joints)
    tgt = _like(_as_tensor(target), pos)
    src = target_offsets(skeleton, pos[0])
    scale = leg_length(skeleton, tgt) / leg_length(skeleton, src)
    quats = inverse_kinematics(skeleton, pos, smooth_forward=False)
    return forward_kinematics(skeleton, tgt, quats, pos[..., 0, :] * scale)


def root_facing_quat(skeleton: Skeleton, pose: Tensor) -> Tensor:
    """Yaw quaternion turning one pose's facing direction (from hips and shoulders) to Z+.

    This is process_file's "face Z+" step, which uses (r_hip, l_hip, r_shoulder, l_shoulder) as named.
    """
    r_hip, l_hip, r_sdr, l_sdr = skeleton.face_joints
    return _to_facing_z(_facing(pose, (l_hip, r_hip), (l_sdr, r_sdr)))
