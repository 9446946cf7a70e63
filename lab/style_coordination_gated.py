"""The coordination map at a strength set per clip by how much of the clip moves where the reference moves: does
a map learnt on one kind of motion spare the clips it has no evidence for?

- output shaper ``coordination_gated`` (``lag``, ``taps``, ``floor`` as ``coordination``; ``share``: the variance
  share of the reference's leading subspace, default 0.99): x -> I + a (M - I), M the product's map and a the share
  of the clip's own (delay-embedded, centred) variance that lies in that subspace;
- output shaper ``moments_gated`` (``floor`` as ``moments``, ``share``): the moment rule's change times the same a.

Why: a map estimated from a squat and its plain squat says nothing about the directions a walk moves in, yet moves
them (synthetic LSO: content lost where a draw's example is a squat, a kick or a wave). Control: ``--row shapers``.
"""

from __future__ import annotations

import numpy as np

from lab.coordination_maps import MapShaper
from motionaug.augment.methods.hooks import ShapeContext, output_shapers
from motionaug.augment.methods.shapers import (
    Moments,
    apply_coordination,
    coordination_map,
    delays,
    position_channels,
)

LAG, TAPS = 3, 6  # the shipped map's delay embedding, the space the evidence is measured in


def leading_basis(reference: np.ndarray, share: float, lag: int = LAG, taps: int = TAPS) -> np.ndarray:
    """The reference's leading principal directions holding ``share`` of its delay-embedded position variance."""
    x = delays(np.asarray(reference[:, position_channels()], np.float64), lag, taps)
    values, vectors = np.linalg.eigh(np.cov(x, rowvar=False))
    order = np.argsort(values)[::-1]
    kept = int(np.searchsorted(np.cumsum(values[order]) / values.sum(), share)) + 1
    return vectors[:, order[:kept]]


def evidence(motion: np.ndarray, basis: np.ndarray, lag: int = LAG, taps: int = TAPS) -> float:
    """The share of the clip's own delay-embedded position variance that lies in ``basis``'s span."""
    x = delays(np.asarray(motion[:, position_channels()], np.float64), lag, taps)
    x = x - x.mean(0)
    return float(((x @ basis) ** 2).sum() / max((x**2).sum(), 1e-12))


class Evidence:
    """Each reference's leading basis, kept, and a clip's share of variance in it (``evidence``)."""

    def __init__(self, share: float) -> None:
        self.share = share
        self._bases: dict[int, np.ndarray] = {}

    def __call__(self, motion: np.ndarray, reference: np.ndarray) -> float:
        key = hash(reference.tobytes())
        if key not in self._bases:
            self._bases[key] = leading_basis(reference, self.share)
        return evidence(motion, self._bases[key])


@output_shapers.register("coordination_gated")
class CoordinationGated(MapShaper):
    """The product's map, blended with the identity by the clip's share of variance in the reference's subspace."""

    def __init__(self, lag: int = LAG, taps: int = TAPS, floor: float = 1e-3, share: float = 0.99) -> None:
        super().__init__(lag, taps, floor)
        self.evidence = Evidence(share)

    def build(self, example: np.ndarray, reference: np.ndarray, cols: np.ndarray) -> np.ndarray:
        return coordination_map(example, reference, 0.0, self.floor, cols, self.lag, self.taps)

    def apply(self, output: np.ndarray, colour: np.ndarray, cols: np.ndarray, context: ShapeContext) -> np.ndarray:
        strength = self.evidence(output, context.reference)
        blended = np.eye(len(colour)) + strength * (colour - np.eye(len(colour)))
        return apply_coordination(output, blended, cols, self.lag, self.taps)


@output_shapers.register("moments_gated")
class MomentsGated(Moments):
    """The moment rule's change, times the clip's share of variance in the reference's subspace (module doc)."""

    def __init__(self, floor: float = 0.25, share: float = 0.99) -> None:
        super().__init__(floor)
        self.evidence = Evidence(share)

    def __call__(self, output: np.ndarray, context: ShapeContext) -> np.ndarray:
        shaped = super().__call__(output, context)
        strength = self.evidence(output, context.reference)
        return (output + strength * (shaped - output)).astype(np.float32)
