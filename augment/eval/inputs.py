"""Turning HumanML3D features into what the evaluators read: joint positions plus a frame mask.

The evaluators (``models.evaluators``) take joints, not features, so that ``models`` never imports
``augment``. The conversion uses ``augment.motion.features.recover_from_ric`` (imported when first needed).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import Skeleton


def features_to_joints(
    features: torch.Tensor | np.ndarray,
    skeleton: Skeleton,
    mean: np.ndarray | None = None,
    std: np.ndarray | None = None,
) -> torch.Tensor:
    """``(..., T, D)`` features (normalised when ``mean``/``std`` are given) -> ``(..., T, J, 3)`` joints.

    Assumes ``recover_from_ric(features, n_joints)`` as in the HumanML3D reference.
    """
    feats = torch.as_tensor(features, dtype=torch.float32)
    if feats.shape[-1] != skeleton.feature_dim:
        raise MotionDataError(
            "features", f"width {feats.shape[-1]} != {skeleton.feature_dim} for skeleton {skeleton.name}"
        )
    if (mean is None) != (std is None):
        raise MotionDataError("features", "give both mean and std to denormalise, or neither")
    if mean is not None and std is not None:
        feats = feats * torch.as_tensor(std, dtype=torch.float32) + torch.as_tensor(mean, dtype=torch.float32)
    from motionaug.augment.motion.features import (
        recover_from_ric,
    )  # written alongside; imported late to keep this module light

    return torch.as_tensor(recover_from_ric(feats, skeleton.n_joints), dtype=torch.float32)


def pad_batch(sequences: Sequence[torch.Tensor | np.ndarray]) -> tuple[torch.Tensor, torch.Tensor]:
    """Stack variable-length ``(T_i, ...)`` arrays into ``(B, T_max, ...)`` zeros-padded, with a ``(B, T_max)`` mask."""
    if not sequences:
        raise MotionDataError("batch", "no sequences to pad")
    items = [torch.as_tensor(s, dtype=torch.float32) for s in sequences]
    tail = items[0].shape[1:]
    if any(s.shape[1:] != tail for s in items):
        raise MotionDataError("batch", "sequences differ in their per-frame shape")
    t_max = max(s.shape[0] for s in items)
    out = torch.zeros(len(items), t_max, *tail)
    mask = torch.zeros(len(items), t_max, dtype=torch.bool)
    for i, s in enumerate(items):
        out[i, : s.shape[0]] = s
        mask[i, : s.shape[0]] = True
    return out, mask
