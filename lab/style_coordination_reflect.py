"""The lagged coordination map with a history that moves: each clip's first frames reflected in time before it,
in place of its first frame repeated.

- output shaper ``coordination_reflect`` (``lag``, ``taps``, ``floor`` as ``coordination``): the product's map and
  its application, the delay embedding padded by reflection (frames 1, 2, ... before frame 0), for the example, the
  reference and the output alike; a clip travelling against the example is played backwards as the product does.

Why: a repeated first frame is a still history, which the map (a filter over the frames before each frame) turns
into a start-up transient over the first 0.9 s (lab/NOTES.md 0). Control: ``--row shapers``.
"""

from __future__ import annotations

import numpy as np

from lab.coordination_maps import MapShaper
from motionaug.augment.methods.hooks import ShapeContext, output_shapers
from motionaug.augment.methods.shapers import _covariance, _power
from motionaug.augment.motion.travel import opposed


def reflected_delays(x: np.ndarray, lag: int, taps: int) -> np.ndarray:
    """(T, F) -> (T, F x (taps + 1)) as ``shapers.delays``, the frames before the clip its first ones reflected."""
    n = lag * taps
    head = x[1 : n + 1][::-1] if len(x) > n else np.repeat(x[:1], n, axis=0)
    padded = np.concatenate([head, x])
    return np.concatenate([padded[n - lag * i : len(padded) - lag * i] for i in range(taps + 1)], axis=1)


@output_shapers.register("coordination_reflect")
class CoordinationReflect(MapShaper):
    """The product's map over a reflected history (module doc)."""

    def build(self, example: np.ndarray, reference: np.ndarray, cols: np.ndarray) -> np.ndarray:
        e, r = (
            _covariance(reflected_delays(np.asarray(m[:, cols], np.float64), self.lag, self.taps), 0.0)
            for m in (example, reference)
        )
        return _power(e, 0.5, self.floor) @ _power(r, -0.5, self.floor)

    def apply(self, output: np.ndarray, colour: np.ndarray, cols: np.ndarray, context: ShapeContext) -> np.ndarray:
        back = opposed(context.content, context.example, context.fps)
        clip = output[::-1].copy() if back else output
        x = reflected_delays(np.asarray(clip[:, cols], np.float64), self.lag, self.taps)
        mean = x.mean(0)
        out = clip.copy()
        out[:, cols] = (mean + (x - mean) @ colour.T)[:, : len(cols)].astype(np.float32)
        return out[::-1].copy() if back else out
