"""The lagged coordination map with the root's velocities among its channels: does judge 2 read how the root moves
with the limbs?

- output shaper ``coordination_root`` (``lag``, ``taps``, ``shrink``, ``floor`` as ``coordination``; ``root``:
  ``lin`` adds the root's ground-plane velocity, ``all`` its yaw rate too): the product's map
  (``augment/methods/shapers.py``) on the root height, the joint positions and those root channels.

Why: judge 2 reads the root velocity beside the joints, and the product's map leaves it the content's, so a
style's sway and surge of the pelvis against the limbs' phase never reaches the output. Control row: ``bench/
bench_lso.py run --row shapers --shapers coordination_root --hook-modules lab.style_coordination_root``.
"""

from __future__ import annotations

import numpy as np

from motionaug.augment.methods.hooks import OutputShaper, ShapeContext, output_shapers
from motionaug.augment.methods.shapers import coordination_transfer, position_channels
from motionaug.augment.motion.features import feature_slices
from motionaug.schemas.skeleton import T2M


def root_channels(root: str) -> np.ndarray:
    """The root velocity channels ``root`` names, then the position channels."""
    slices = feature_slices(T2M)
    names = {"lin": ["root_lin_vel"], "all": ["root_rot_vel", "root_lin_vel"]}
    if root not in names:
        raise ValueError(f"coordination_root: root must be lin or all, got {root!r}")
    extra = [np.arange(slices[n].start, slices[n].stop) for n in names[root]]
    return np.r_[np.concatenate(extra), position_channels()]


@output_shapers.register("coordination_root")
class CoordinationRoot(OutputShaper):
    """The product's coordination map with root velocities among its channels (module doc)."""

    needs_reference = True

    def __init__(
        self, root: str = "lin", lag: int = 3, taps: int = 6, shrink: float = 0.0, floor: float = 1e-3
    ) -> None:
        self.cols, self.lag, self.taps, self.shrink, self.floor = root_channels(root), lag, taps, shrink, floor

    def __call__(self, output: np.ndarray, context: ShapeContext) -> np.ndarray:
        if context.reference is None:
            raise ValueError("the coordination_root shaper needs the example's reference")
        return coordination_transfer(
            output, context.example, context.reference, self.shrink, self.floor, self.cols, self.lag, self.taps
        )
