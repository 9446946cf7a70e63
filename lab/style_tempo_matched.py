"""The shipped chain at the example's pace: does a map measured between clips of one cadence keep the content?
(Adopted with ``gait=true alike=true`` as the product's ``match_tempo``, first in ``STYLE_ERD_CHAIN``; bit-identical.)

- output shaper ``tempo_matched`` (``keep_clock``: play the result back at the content's clock, default false;
  ``cap``: most frames of a retimed clip, default 196; ``gait``: keep the clock where the example and its reference
  are different gaits; ``alike``: keep it where the content does not move as the example does): the example's cycle
  period over its reference's (``augment.motion.tempo.style_tempo``, one reference allowed) gives a tempo; the
  reference, the content and the output are retimed to it, then the rest of ``STYLE_ERD_CHAIN`` runs on them.

Why: ``coordination``'s lagged covariances and ``moments``' variances compare the example with a reference that
walks at another cadence (synthetic ``sneaky`` and ``old`` walks are half a plain walk's pace), so the map carries
the cadence as a change of coordination, and applied at the content's own cadence it lengthens strides and turns
walks into runs and turns. With the reference at the example's pace the map holds only what the style changes at a
given cadence. Control: ``bench/bench_lso.py run --row shapers --shapers example_tempo --hook-modules lab.style_tempo``
(the content retimed alone).
"""

from __future__ import annotations

import numpy as np

from motionaug.augment.methods.hooks import OutputShaper, ShapeContext, output_shapers
from motionaug.augment.methods.shapers import FLIGHT_APART, STYLE_ERD_CHAIN, flight
from motionaug.augment.motion.tempo import retime, style_tempo
from motionaug.augment.motion.travel import travels


def fitted(motion: np.ndarray, frames: int) -> np.ndarray:
    """``motion`` cut or padded (its last frame repeated) to ``frames``."""
    if len(motion) >= frames:
        return motion[:frames]
    return np.concatenate([motion, np.repeat(motion[-1:], frames - len(motion), axis=0)])


@output_shapers.register("tempo_matched")
class TempoMatched(OutputShaper):
    """The shipped chain with the reference, the content and the output at the example's pace (module doc)."""

    needs_reference = True

    def __init__(self, keep_clock: bool = False, cap: int = 196, gait: bool = False, alike: bool = False) -> None:
        self.keep_clock, self.cap, self.gait, self.alike = keep_clock, cap, gait, alike
        self.chain = output_shapers.create_all([s for s in STYLE_ERD_CHAIN if s != "match_tempo"])

    def __call__(self, output: np.ndarray, context: ShapeContext) -> np.ndarray:
        if context.reference is None:
            raise ValueError("the tempo_matched shaper needs the example's reference")
        tempo, _ = style_tempo([(context.example, context.fps)], [(context.reference, context.fps)], min_references=1)
        tempo = 1.0 if tempo is None else tempo
        if self.gait and abs(flight(context.example) - flight(context.reference)) > FLIGHT_APART:
            tempo = 1.0
        if self.alike and travels(context.content, context.fps) != travels(context.example, context.fps):
            tempo = 1.0
        frames = max(len(output), self.cap)
        content = retime(context.content, tempo, frames)
        shaped = retime(output, tempo, frames)[: len(content)]
        reference = retime(context.reference, tempo, max(len(context.reference), self.cap))
        inner = ShapeContext(content, context.example, reference, context.fps, context.alike)
        for shaper in self.chain:
            shaped = shaper(shaped, inner)
        if not self.keep_clock or tempo == 1.0:
            return shaped
        return fitted(retime(shaped, 1.0 / tempo, max(len(output), len(shaped))), len(output))
