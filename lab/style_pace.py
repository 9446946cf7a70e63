"""The example's ground speed over its reference's as an output step: does judge 1 read how fast the style
travels?

- output shaper ``example_pace`` (``most``: the largest factor either way, default 3): the output's root carried
  ``ground_speed(example) / ground_speed(reference)`` times as far each frame (``augment.motion.tempo.paced``).

Why: judge 1 reads world joint positions, the root's path included, and every output step keeps the content's
path; an ``elderly`` walk that covers a young walk's ground at the young walk's clock reads as neither. Put after
``lock_feet`` (which would restore the legs' pace) and before ``plant_feet`` (which holds the feet on the new path).
Control row: ``bench/bench_lso.py run --row shapers --shapers example_pace --hook-modules lab.style_pace``.
"""

from __future__ import annotations

import numpy as np

from motionaug.augment.methods.hooks import OutputShaper, ShapeContext, output_shapers
from motionaug.augment.motion.tempo import ground_speed, paced


@output_shapers.register("example_pace")
class ExamplePace(OutputShaper):
    """The output's ground speed scaled by the example's over its reference's (module doc)."""

    needs_reference = True

    def __init__(self, most: float = 3.0) -> None:
        self.most = most

    def __call__(self, output: np.ndarray, context: ShapeContext) -> np.ndarray:
        if context.reference is None:
            raise ValueError("the example_pace shaper needs the example's reference")
        ratio = ground_speed(context.example) / max(ground_speed(context.reference), 1e-9)
        return paced(output, float(np.clip(ratio, 1.0 / self.most, self.most)))
