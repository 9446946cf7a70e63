"""Variable-length clips as one padded batch with a frame mask, the shape every network and evaluator reads."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from motionaug.schemas.errors import MotionDataError


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
