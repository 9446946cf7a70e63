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
