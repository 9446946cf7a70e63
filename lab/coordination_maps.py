"""The shape every lab variant of the coordination map shares: a map built once per example and reference, applied
to each output as the product's ``coordination`` applies its own (``augment/methods/shapers.apply_coordination``).

A variant subclasses ``MapShaper``, registers itself as an output shaper and gives ``build`` (and ``apply`` where it
applies the map otherwise).
"""

from __future__ import annotations

import numpy as np

from motionaug.augment.methods.hooks import OutputShaper, ShapeContext
from motionaug.augment.methods.shapers import apply_coordination, position_channels


class MapShaper(OutputShaper):
    """An output shaper x -> M x over the position channels, each frame stacked with ``taps`` frames ``lag`` apart,
    M from ``build`` and kept per (example, reference)."""

    needs_reference = True

    def __init__(self, lag: int = 3, taps: int = 6, floor: float = 1e-3) -> None:
        self.lag, self.taps, self.floor = lag, taps, floor
        self._maps: dict[int, np.ndarray] = {}

    def build(self, example: np.ndarray, reference: np.ndarray, cols: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def apply(self, output: np.ndarray, colour: np.ndarray, cols: np.ndarray, context: ShapeContext) -> np.ndarray:
        """The map on one output, as the product's ``coordination`` applies it (a variant may apply it otherwise)."""
        return apply_coordination(output, colour, cols, self.lag, self.taps)

    def __call__(self, output: np.ndarray, context: ShapeContext) -> np.ndarray:
        if context.reference is None:
            raise ValueError(f"{type(self).__name__} needs the example's reference")
        cols = position_channels()
        key = hash((context.example.tobytes(), context.reference.tobytes()))
        if key not in self._maps:
            self._maps[key] = self.build(context.example, context.reference, cols)
        return self.apply(output, self._maps[key], cols, context)
