"""The coordination map applied only inside the reference's own subspace: does a walk's map carry better to a wave
when the directions a walk never moves in are left as the content has them?

- output shaper ``coordination_subspace`` (``lag``, ``taps``, ``floor`` as ``coordination``; ``keep``: the share of
  the reference's variance its subspace holds): x -> A P x + (I - P) x, A the product's whitening-colouring map, P the
  projector on the reference's leading principal directions (delay-embedded) that hold ``keep`` of its variance.

Why: outside a walk's subspace (an arm raised overhead) S_r^(-1/2) divides by the eigenvalue floor, so the map
there is noise scaled up, not the style. Control: ``--row shapers --shapers coordination_subspace``.
"""

from __future__ import annotations

import numpy as np

from lab.coordination_maps import MapShaper
from motionaug.augment.methods.hooks import output_shapers
from motionaug.augment.methods.shapers import _covariance, coordination_map, delays


def subspace_map(
    example: np.ndarray, reference: np.ndarray, cols: np.ndarray, lag: int, taps: int, floor: float, keep: float
) -> np.ndarray:
    """A P + I - P (module doc)."""
    colour = coordination_map(example, reference, 0.0, floor, cols, lag, taps)
    values, vectors = np.linalg.eigh(_covariance(delays(np.asarray(reference[:, cols], np.float64), lag, taps), 0.0))
    order = np.argsort(values)[::-1]
    share = np.cumsum(values[order]) / values.sum()
    n = int(np.searchsorted(share, keep) + 1)
    basis = vectors[:, order[:n]]
    projector = basis @ basis.T
    eye = np.eye(len(colour))
    return colour @ projector + eye - projector


@output_shapers.register("coordination_subspace")
class CoordinationSubspace(MapShaper):
    """The product's map inside the reference's subspace, identity outside (module doc)."""

    def __init__(self, lag: int = 3, taps: int = 6, floor: float = 1e-3, keep: float = 0.99) -> None:
        super().__init__(lag, taps, floor)
        self.keep = keep

    def build(self, example: np.ndarray, reference: np.ndarray, cols: np.ndarray) -> np.ndarray:
        return subspace_map(example, reference, cols, self.lag, self.taps, self.floor, self.keep)
