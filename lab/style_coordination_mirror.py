"""The coordination map from each example and its reference together with their mirror images: does a symmetric,
twice-sampled covariance carry the style better than one take's?

- output shaper ``coordination_mirror`` (``lag``, ``taps``, ``floor`` as ``coordination``): the product's map with
  S_e and S_r each the mean of the clip's and its left-right mirror's (delay-embedded) covariances.

Why: one take gives a few hundred frames for a 448-dimensional covariance, and a style is mostly the same on both
sides, so the mirror is a second sample of it (the issue's example augmentation). Control: ``--row shapers``.
"""

from __future__ import annotations

import numpy as np

from motionaug.augment.methods.hooks import OutputShaper, ShapeContext, output_shapers
from motionaug.augment.methods.shapers import _covariance, _power, apply_coordination, delays, position_channels
from motionaug.augment.motion.features import mirror_features


def mirrored_covariance(motion: np.ndarray, cols: np.ndarray, lag: int, taps: int) -> np.ndarray:
    """The mean of the clip's and its mirror's delay-embedded covariances over ``cols``."""
    clips = (motion, mirror_features(np.asarray(motion, np.float32)))
    return sum(_covariance(delays(np.asarray(m[:, cols], np.float64), lag, taps), 0.0) for m in clips) / 2


@output_shapers.register("coordination_mirror")
class CoordinationMirror(OutputShaper):
    """The product's map from mirror-pooled covariances (module doc)."""

    needs_reference = True

    def __init__(self, lag: int = 3, taps: int = 6, floor: float = 1e-3) -> None:
        self.lag, self.taps, self.floor = lag, taps, floor
        self._maps: dict[int, np.ndarray] = {}

    def __call__(self, output: np.ndarray, context: ShapeContext) -> np.ndarray:
        if context.reference is None:
            raise ValueError("the coordination_mirror shaper needs the example's reference")
        cols = position_channels()
        key = hash((context.example.tobytes(), context.reference.tobytes()))
        if key not in self._maps:
            e, r = (mirrored_covariance(m, cols, self.lag, self.taps) for m in (context.example, context.reference))
            self._maps[key] = _power(e, 0.5, self.floor) @ _power(r, -0.5, self.floor)
        return apply_coordination(output, self._maps[key], cols, self.lag, self.taps)
