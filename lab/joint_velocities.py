"""Joint velocities re-derived from the final joint positions: does judge 1 read the stale velocities?

- output shaper ``velocities``: the ``local_vel`` block recomputed from the output's own joint positions and root
  path as the features define it (each joint's step t -> t+1 in the root frame of t; the last frame's row kept).

Why: the coordination map, the bone lengths and the foot planting move the joint positions and leave the
velocity channels the network's, so the features disagree with themselves; judge 1 reads both. Control row:
``bench/bench_lso.py run --row shapers --shapers velocities --hook-modules lab.joint_velocities``.
"""

from __future__ import annotations

import numpy as np
import torch

from motionaug.augment.methods.hooks import OutputShaper, ShapeContext, output_shapers
from motionaug.augment.motion.features import feature_slices, recover_from_ric, recover_root_rot_pos
from motionaug.augment.motion.rotations import qrot
from motionaug.schemas.skeleton import T2M


def with_velocities(features: np.ndarray) -> np.ndarray:
    """``features`` (T, D) whose joint velocity rows 0 .. T-2 are the steps of its own joint positions."""
    if len(features) < 2:
        return features.copy()
    data = torch.as_tensor(features, dtype=torch.float64)
    r_rot, _ = recover_root_rot_pos(data)
    world = recover_from_ric(data, T2M.n_joints)
    steps = qrot(r_rot[:-1, None].expand(-1, T2M.n_joints, -1), world[1:] - world[:-1])
    out = features.copy()
    out[:-1, feature_slices(T2M)["local_vel"]] = steps.reshape(len(features) - 1, -1).numpy().astype(features.dtype)
    return out


@output_shapers.register("velocities")
class Velocities(OutputShaper):
    """The velocity channels re-derived from the output's positions (module doc)."""

    def __call__(self, output: np.ndarray, context: ShapeContext) -> np.ndarray:
        return with_velocities(output)
