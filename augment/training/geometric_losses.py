"""MDM's geometric losses (Tevet et al. 2023, sec. 3): joint positions, joint velocities, foot contact.

The x0 loss alone lets small feature errors add up to floating or sliding bodies once the features
are integrated into joints; these terms score the prediction where it matters, in metres. All take
*de-normalised* HumanML3D features ``(B, T, D)`` and a frame mask ``(B, T)`` (True = real frame); padded
frames are selected away with ``where``, so nothing in the padding can reach the loss or its gradient.
Each function returns a per-sample loss ``(B,)``.
"""

from __future__ import annotations

import torch
from torch import Tensor

from motionaug.augment.motion.features import feature_slices, recover_from_ric
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import T2M, Skeleton

CONTACT_THRESHOLD = 0.5  # the feet channels are 0/1 in the data; above this the foot is planted


def _masked_mean(values: Tensor, mask: Tensor) -> Tensor:
    """Mean of ``values (B, T, ...)`` over the frames where ``mask (B, T)`` is True, per sample ``(B,)``."""
    keep = mask.reshape(mask.shape + (1,) * (values.dim() - 2))
    kept = torch.where(keep, values, torch.zeros((), dtype=values.dtype, device=values.device))
    per_frame = values[0, 0].numel() if values.dim() > 2 else 1
    counts = mask.sum(dim=1).clamp(min=1) * per_frame
    return kept.reshape(values.shape[0], -1).sum(dim=1) / counts


def _pair_mask(mask: Tensor) -> Tensor:
    """Frames t whose velocity (t+1 minus t) joins two real frames, (B, T-1)."""
    return mask[:, 1:] & mask[:, :-1]


def _check(pred: Tensor, target: Tensor, mask: Tensor | None, what: str) -> Tensor:
    if pred.shape != target.shape:
        raise MotionDataError(what, f"prediction {tuple(pred.shape)} != target {tuple(target.shape)}")
    if mask is None:
        return torch.ones(pred.shape[:2], dtype=torch.bool, device=pred.device)
    if mask.shape != pred.shape[:2]:
        raise MotionDataError(what, f"mask {tuple(mask.shape)} != (B, T) {tuple(pred.shape[:2])}")
    return mask.bool()


def features_to_positions(features: Tensor, mask: Tensor, skeleton: Skeleton = T2M) -> Tensor:
    """Differentiable joints ``(B, T, J, 3)``; padding is zeroed first so the integration stays finite."""
    clean = torch.where(mask[..., None], features, torch.zeros((), dtype=features.dtype, device=features.device))
    return recover_from_ric(clean, skeleton.n_joints)


def joint_position_loss(pred_joints: Tensor, target_joints: Tensor, mask: Tensor | None = None) -> Tensor:
    """Mean squared joint-position error over real frames (MDM's L_pos)."""
    mask = _check(pred_joints, target_joints, mask, "joint_position_loss")
    return _masked_mean((pred_joints - target_joints).square(), mask)


def joint_velocity_loss(pred_joints: Tensor, target_joints: Tensor, mask: Tensor | None = None) -> Tensor:
    """Mean squared error of per-frame joint displacements between real frames (MDM's L_vel)."""
    mask = _check(pred_joints, target_joints, mask, "joint_velocity_loss")
    pred_vel = pred_joints[:, 1:] - pred_joints[:, :-1]
    target_vel = target_joints[:, 1:] - target_joints[:, :-1]
    return _masked_mean((pred_vel - target_vel).square(), _pair_mask(mask))


def foot_joints(skeleton: Skeleton = T2M) -> list[int]:
    """Joint indices in the order of the features' contact channels: left ankle, left toe, right ankle, right toe."""
    return [*skeleton.feet_left, *skeleton.feet_right]


def foot_contact_loss(
    pred_joints: Tensor,
    target_joints: Tensor,
    target_contacts: Tensor,
    mask: Tensor | None = None,
    skeleton: Skeleton = T2M,
) -> Tensor:
    """Foot velocity error on frames where the target says the foot is planted (MDM's L_foot).

    MDM penalises the predicted foot velocity itself there; this compares it with the target's, which is
    near zero on planted frames anyway, so the loss is exactly zero for a perfect prediction.
    ``target_contacts (B, T, 4)`` are the target's feet channels (de-normalised: 0 or 1).
    """
    mask = _check(pred_joints, target_joints, mask, "foot_contact_loss")
    if target_contacts.shape != pred_joints.shape[:2] + (4,):
        raise MotionDataError("foot_contact_loss", f"contacts {tuple(target_contacts.shape)} != (B, T, 4)")
    feet = foot_joints(skeleton)
    pred_vel = pred_joints[:, 1:, feet] - pred_joints[:, :-1, feet]  # (B, T-1, 4, 3)
    target_vel = target_joints[:, 1:, feet] - target_joints[:, :-1, feet]
    error = (pred_vel - target_vel).square().sum(dim=-1)  # (B, T-1, 4)
    planted = target_contacts[:, :-1] > CONTACT_THRESHOLD
    error = torch.where(planted, error, torch.zeros((), dtype=error.dtype, device=error.device))
    return _masked_mean(error, _pair_mask(mask))


def geometric_losses(
    pred_features: Tensor, target_features: Tensor, mask: Tensor | None = None, skeleton: Skeleton = T2M
) -> dict[str, Tensor]:
    """``{"pos", "vel", "foot"}`` per-sample losses ``(B,)`` from de-normalised features ``(B, T, D)``."""
    mask = _check(pred_features, target_features, mask, "geometric_losses")
    pred_joints = features_to_positions(pred_features, mask, skeleton)
    with torch.no_grad():
        target_joints = features_to_positions(target_features, mask, skeleton)
    contacts = target_features[..., feature_slices(skeleton)["feet"]]
    return {
        "pos": joint_position_loss(pred_joints, target_joints, mask),
        "vel": joint_velocity_loss(pred_joints, target_joints, mask),
        "foot": foot_contact_loss(pred_joints, target_joints, contacts, mask, skeleton),
    }
