"""Foot locking in feature space: move the root so that a planted foot stays where it was planted.

A transfer that keeps the content's root path but changes the legs (a shorter stride, a shuffle) makes planted feet
slide: the path says the body travels further than the legs push it. So the root's step over each frame transition
is corrected by the horizontal slide of the planted toe (below ``height`` in both frames, the rule of
``augment.metrics.foot_skating_ratio``; the lower toe when both are). Poses are untouched; the root velocity and the
local joint velocities that include it are rewritten consistently.
"""

from __future__ import annotations

import numpy as np
import torch

from motionaug.augment.motion.features import feature_slices, recover_from_ric, recover_root_rot_pos
from motionaug.augment.motion.rotations import qrot
from motionaug.schemas.skeleton import T2M, Skeleton


def lock_feet(features: np.ndarray, skeleton: Skeleton = T2M, height: float = 0.05) -> np.ndarray:
    """``features`` (T, D) with root steps corrected so a planted toe does not slide; same dtype and shape."""
    if features.shape[0] < 2:
        return features.copy()
    blocks = feature_slices(skeleton)
    data = torch.as_tensor(features, dtype=torch.float64)
    joints = recover_from_ric(data, skeleton.n_joints)  # (T, J, 3)
    r_rot, _ = recover_root_rot_pos(data)  # (T, 4): yaw quaternions world -> root frame
    toes = joints[:, [skeleton.feet_left[1], skeleton.feet_right[1]]]  # (T, 2, 3)
    low = toes[..., 1] < height
    planted = low[1:] & low[:-1]  # (T-1, 2)
    lower = toes[1:, :, 1] + toes[:-1, :, 1]  # (T-1, 2): the foot to hold when both are planted
    held = torch.where(planted[:, 0] & planted[:, 1], lower.argmin(-1), planted[:, 1].long())  # (T-1,)
    slide = (toes[1:] - toes[:-1]).gather(1, held[:, None, None].expand(-1, 1, 3))[:, 0]  # (T-1, 3)
    correction = -slide * torch.tensor([1.0, 0.0, 1.0], dtype=data.dtype)
    correction = correction * planted.any(-1, keepdim=True)  # (T-1, 3) world-frame change of the root step

    out = data.clone()
    # root_lin_vel[t] is the step t -> t+1 in the root frame of t+1 (features.extract_features_and_joints)
    step_fix = qrot(r_rot[1:], correction)
    out[:-1, blocks["root_lin_vel"]] += step_fix[:, [0, 2]]
    # local_vel[t] is every joint's step t -> t+1 in the root frame of t: all of them move with the root
    vel_fix = qrot(r_rot[:-1], correction)
    local = out[:-1, blocks["local_vel"]].reshape(-1, skeleton.n_joints, 3) + vel_fix[:, None, :]
    out[:-1, blocks["local_vel"]] = local.reshape(local.shape[0], -1)
    return out.numpy().astype(features.dtype)


def _segments(mask: np.ndarray) -> list[tuple[int, int]]:
    """Runs of True in a 1-d mask as (first, last) frame pairs, inclusive."""
    edges = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1))


def _pin_offsets(toe_xz: np.ndarray, contact: np.ndarray, blend: int) -> np.ndarray:
    """(T, 2) ground-plane offsets that hold the toe at its median place over each contact run (robust to the fast
    frames a run can start or end with), faded to zero over ``blend`` frames on either side of a run (the nearest
    run's offset wins) so the swing joins without a jump."""
    offsets = np.zeros_like(toe_xz)
    weight = np.zeros(len(toe_xz))
    for first, last in _segments(contact):
        target = np.median(toe_xz[first : last + 1], axis=0)
        offsets[first : last + 1] = target - toe_xz[first : last + 1]
        weight[first : last + 1] = 1.0
        for side, edge in ((-1, first), (1, last)):
            for step in range(1, blend + 1):
                t = edge + side * step
                w = 1.0 - step / (blend + 1)
                if 0 <= t < len(toe_xz) and not contact[t] and w > weight[t]:
                    offsets[t], weight[t] = offsets[edge] * w, w
    return offsets


def _knee(hip: np.ndarray, knee: np.ndarray, ankle: np.ndarray, thigh: float, shin: float) -> np.ndarray:
    """Two-bone IK: the knee (T, 3) that joins ``hip`` and ``ankle`` with the given bone lengths, bent toward the
    old knee's side; an ankle out of reach is taken to the nearest reachable distance along the hip-ankle line."""
    axis = ankle - hip
    dist = np.linalg.norm(axis, axis=-1, keepdims=True)
    unit = axis / np.maximum(dist, 1e-9)
    dist = np.clip(dist, abs(thigh - shin) + 1e-6, thigh + shin - 1e-6)
    along = (thigh**2 - shin**2 + dist**2) / (2 * dist)
    radius = np.sqrt(np.maximum(thigh**2 - along**2, 0.0))
    bend = knee - hip
    bend = bend - (bend * unit).sum(-1, keepdims=True) * unit
    bend = bend / np.maximum(np.linalg.norm(bend, axis=-1, keepdims=True), 1e-9)
    return hip + along * unit + radius * bend


def plant_feet(
    features: np.ndarray,
    contacts: np.ndarray,
    skeleton: Skeleton = T2M,
    blend: int = 4,
    clearance: np.ndarray | None = None,
) -> np.ndarray:
    """``features`` (T, D) whose toes stay put wherever ``contacts`` (T, 2: left, right toe) says a foot is planted,
    and, with ``clearance`` (T, 2: least toe heights), swing no lower than it elsewhere.

    Each contact run holds its toe (and its ankle, by the same shift) at the toe's median ground-plane place over the
    run; a swinging toe below its clearance is raised to it; the knee is solved by two-bone IK from the hip with the
    output's own thigh and shin lengths, so bones keep their lengths. Why: a whole-body map of the joint positions
    moves the legs while the root path stays the content's, so in double support the foot ``lock_feet`` does not
    hold slides, and a swinging toe skims the floor; the contacts and heights come from the content because the
    transfer keeps its footfalls. Only the joint positions of the legs change.
    """
    if features.shape[0] < 2:
        return features.copy()
    data = torch.as_tensor(features, dtype=torch.float64)
    r_rot, r_pos = recover_root_rot_pos(data)
    world = recover_from_ric(data, skeleton.n_joints).numpy()  # (T, J, 3)
    parents = skeleton.parents
    for side, (ankle, toe) in enumerate((skeleton.feet_left, skeleton.feet_right)):
        knee = parents[ankle]
        hip = parents[knee]
        flags = contacts[:, side].astype(bool)
        shift = _pin_offsets(world[:, toe, [0, 2]], flags, blend)
        lift = np.zeros(len(world))
        if clearance is not None:
            lift = np.where(flags, 0.0, np.maximum(clearance[:, side] - world[:, toe, 1], 0.0))
        if not shift.any() and not lift.any():
            continue
        thigh = float(np.linalg.norm(world[:, knee] - world[:, hip], axis=-1).mean())
        shin = float(np.linalg.norm(world[:, ankle] - world[:, knee], axis=-1).mean())
        moved = world[:, ankle].copy()
        moved[:, [0, 2]] += shift
        moved[:, 1] += lift
        new_knee = _knee(world[:, hip], world[:, knee], moved, thigh, shin)
        unit = (moved - new_knee) / np.maximum(np.linalg.norm(moved - new_knee, axis=-1, keepdims=True), 1e-9)
        new_ankle = new_knee + unit * shin  # where the ankle was out of reach, the nearest reachable place
        world[:, toe] += new_ankle - world[:, ankle]
        world[:, knee], world[:, ankle] = new_knee, new_ankle
    ground = (
        torch.as_tensor(world[:, 1:], dtype=torch.float64)
        - torch.stack([r_pos[:, 0], torch.zeros_like(r_pos[:, 0]), r_pos[:, 2]], dim=-1)[:, None, :]
    )
    ric = qrot(r_rot[:, None, :].expand(-1, skeleton.n_joints - 1, -1), ground)
    out = features.copy()
    out[:, feature_slices(skeleton)["ric"]] = ric.reshape(len(features), -1).numpy().astype(features.dtype)
    return out
