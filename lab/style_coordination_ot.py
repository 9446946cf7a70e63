"""The coordination map as the optimal transport map between the reference's and the example's (lagged) covariances,
and a strength on either map.

- output shaper ``coordination_ot`` (``lag``, ``taps``, ``floor`` as ``coordination``; ``strength``): x -> (I +
  s (T - I)) x with T = S_r^(-1/2) (S_r^(1/2) S_e S_r^(1/2))^(1/2) S_r^(-1/2), the Monge map between two zero-mean
  Gaussians (Mroueh, "Wasserstein style transfer", AISTATS 2020), s = 1 the map itself, s > 1 beyond it along
  McCann's interpolation;
- ``coordination_strength`` (same settings): the product's whitening-colouring map A as I + s (A - I).

Why: of all maps taking S_r to S_e, T moves a frame least, so it should keep more of the content for the same
covariance change; the product's A adds a rotation that T does not. Control: ``--row shapers`` with each.
"""

from __future__ import annotations

import numpy as np

from lab.coordination_maps import MapShaper
from motionaug.augment.methods.hooks import output_shapers
from motionaug.augment.methods.shapers import _covariance, _power, coordination_map, delays


def ot_map(
    example: np.ndarray, reference: np.ndarray, cols: np.ndarray, lag: int, taps: int, floor: float
) -> np.ndarray:
    """T = S_r^(-1/2) (S_r^(1/2) S_e S_r^(1/2))^(1/2) S_r^(-1/2) over the delay-embedded ``cols``."""
    e, r = (_covariance(delays(np.asarray(m[:, cols], dtype=np.float64), lag, taps), 0.0) for m in (example, reference))
    root, inverse_root = _power(r, 0.5, floor), _power(r, -0.5, floor)
    middle = root @ e @ root
    return inverse_root @ _power((middle + middle.T) / 2, 0.5, floor) @ inverse_root


class _Strength(MapShaper):
    """A map at a strength: I + s (M - I), M from ``base_map``."""

    def __init__(self, lag: int = 3, taps: int = 6, floor: float = 1e-3, strength: float = 1.0) -> None:
        super().__init__(lag, taps, floor)
        self.strength = strength

    def base_map(self, example: np.ndarray, reference: np.ndarray, cols: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def build(self, example: np.ndarray, reference: np.ndarray, cols: np.ndarray) -> np.ndarray:
        base = self.base_map(example, reference, cols)
        return np.eye(len(base)) + self.strength * (base - np.eye(len(base)))


@output_shapers.register("coordination_ot")
class CoordinationOT(_Strength):
    """The Monge map between the covariances, at a strength (module doc)."""

    def base_map(self, example: np.ndarray, reference: np.ndarray, cols: np.ndarray) -> np.ndarray:
        return ot_map(example, reference, cols, self.lag, self.taps, self.floor)


@output_shapers.register("coordination_strength")
class CoordinationStrength(_Strength):
    """The product's whitening-colouring map at a strength (module doc)."""

    def base_map(self, example: np.ndarray, reference: np.ndarray, cols: np.ndarray) -> np.ndarray:
        return coordination_map(example, reference, 0.0, self.floor, cols, self.lag, self.taps)
