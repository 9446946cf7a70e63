"""The coordination map from each example and its reference together with their mirror images: does a symmetric,
twice-sampled covariance carry the style better than one take's?

- output shaper ``coordination_mirror`` (``lag``, ``taps``, ``floor`` as ``coordination``): the product's map with
  S_e and S_r each the mean of the clip's and its left-right mirror's (delay-embedded) covariances.

Why: one take gives a few hundred frames for a 448-dimensional covariance, and a style is mostly the same on both
sides, so the mirror is a second sample of it (the issue's example augmentation). Control: ``--row shapers``.
"""

from __future__ import annotations

import numpy as np

from lab.coordination_maps import MapShaper
from motionaug.augment.methods.hooks import output_shapers
from motionaug.augment.methods.shapers import _covariance, _power, delays
from motionaug.augment.motion.features import mirror_features


def mirrored_covariance(motion: np.ndarray, cols: np.ndarray, lag: int, taps: int) -> np.ndarray:
    """The mean of the clip's and its mirror's delay-embedded covariances over ``cols``."""
    clips = (motion, mirror_features(np.asarray(motion, np.float32)))
    return sum(_covariance(delays(np.asarray(m[:, cols], np.float64), lag, taps), 0.0) for m in clips) / 2


@output_shapers.register("coordination_mirror")
class CoordinationMirror(MapShaper):
    """The product's map from mirror-pooled covariances (module doc)."""

    def build(self, example: np.ndarray, reference: np.ndarray, cols: np.ndarray) -> np.ndarray:
        e, r = (mirrored_covariance(m, cols, self.lag, self.taps) for m in (example, reference))
        return _power(e, 0.5, self.floor) @ _power(r, -0.5, self.floor)
