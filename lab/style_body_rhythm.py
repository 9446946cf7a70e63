"""A style example's body rhythm on a clip that stays in place: how does a style move a standing body?

- output shaper ``body_rhythm`` (``gain``, ``source``, ``example_kind``, ``highpass_s``, ``excess``): on a clip that
  stays in place, shaped by an example that travels (``example_kind=in_place``: by one that stays in place too, a wave
  for a wave), the example's root height and trunk deviations from their means over its frames (the bounce and the
  trunk's sway of its gait or of its standing action), looped to the clip's length and scaled by ``gain``, added to the
  output: the bounce, below the standing height only, lowers the pelvis and everything above the knees, a trunk
  joint's shift carries the arm hanging from it; the knees are left to ``plant_feet`` (two-bone IK to the feet, which
  stay), the step after it.
  ``highpass_s``: each deviation less its moving average over that many seconds first, so a take's slow drift (a
  stoop deepening over a wave) does not loop as a saw.
  ``source=reference``: the same step with the example's reference (the plain take's rhythm): its control.
  ``excess=true``: each channel scaled by sqrt(1 - its variance in the reference over the example's), so the added
  motion is the part of the example's that its plain reference lacks (none where the style moves the body as plainly).

The product's ``in_place_rhythm`` (``augment/methods/shapers.py``) is this step with ``example_kind=in_place``,
``highpass_s=1.0`` and ``excess=true``, the setting it won with (lab/NOTES.md 0); the other settings and the
reference's control stay here, on the product's functions.

Why: on the Bandai-2 train takes a style's standing actions (waves, raises) move the root height, legs and trunk far
more than the plain ones, where the arms' spread changes less; a plain wave barely moves its body, so no map of its
positions can give it the style's body motion. A walk example's gait rhythm is the one body motion of the style it
shows; a wave example shows the standing one (lab/NOTES.md 0).
"""

from __future__ import annotations

import numpy as np

from motionaug.augment.methods.hooks import OutputShaper, ShapeContext, output_shapers
from motionaug.augment.methods.shapers import beyond_reference, body_rhythm, with_body_rhythm
from motionaug.augment.motion.travel import travels


@output_shapers.register("body_rhythm")
class BodyRhythm(OutputShaper):
    """A travelling example's bounce and trunk sway on a clip in place (module doc)."""

    needs_reference = True

    def __init__(
        self,
        gain: float = 1.0,
        source: str = "example",
        example_kind: str = "travels",
        excess: bool = False,
        highpass_s: float = 0.0,
    ) -> None:
        if gain < 0 or source not in ("example", "reference") or example_kind not in ("travels", "in_place"):
            raise ValueError(
                "body_rhythm needs gain >= 0, source example|reference and example_kind travels|in_place, "
                f"got {gain}, {source!r}, {example_kind!r}"
            )
        self.gain, self.source, self.example_travels = gain, source, example_kind == "travels"
        self.excess, self.highpass_s = excess, highpass_s

    def __call__(self, output: np.ndarray, context: ShapeContext) -> np.ndarray:
        if context.reference is None:
            raise ValueError("body_rhythm needs the example's reference")
        if travels(context.content, context.fps) or travels(context.example, context.fps) != self.example_travels:
            return output
        width = round(self.highpass_s * context.fps)
        source = context.example if self.source == "example" else context.reference
        drop, sway = body_rhythm(np.asarray(source), len(output), width)
        if self.excess:
            drop, sway = beyond_reference(drop, sway, body_rhythm(np.asarray(context.reference), len(output), width))
        return with_body_rhythm(output, drop, sway, self.gain)
