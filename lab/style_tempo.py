"""The example's tempo as the last output step: does judge 2 read the style's pace once the coordination is there?

- output shaper ``example_tempo`` (``cap``: most frames of a retimed clip, default 196): the output played at the
  example's cycle period over its reference's (``augment.motion.tempo.style_tempo`` with one reference allowed),
  its clock kept when either does not repeat.

Why: the coordination map's lagged covariances are the example's at the example's pace; at the content's pace the
same phase relations sit at other lags (the real ``elderly`` take is 2.6 times slower than its reference). Control:
``bench/bench_lso.py run --row shapers --shapers example_tempo --hook-modules lab.style_tempo`` (the content clip
retimed, no network).
"""

from __future__ import annotations

import numpy as np

from motionaug.augment.methods.hooks import OutputShaper, ShapeContext, output_shapers
from motionaug.augment.motion.tempo import retime, style_tempo


@output_shapers.register("example_tempo")
class ExampleTempo(OutputShaper):
    """The output at the example's pace over its reference's (module doc)."""

    needs_reference = True

    def __init__(self, cap: int = 196) -> None:
        self.cap = cap

    def __call__(self, output: np.ndarray, context: ShapeContext) -> np.ndarray:
        if context.reference is None:
            raise ValueError("the example_tempo shaper needs the example's reference")
        tempo, _ = style_tempo([(context.example, context.fps)], [(context.reference, context.fps)], min_references=1)
        if tempo is None or tempo == 1.0:
            return output
        return retime(output, tempo, max(len(output), self.cap))
