"""The moment rule's amplitude as a gain (the example's spread over its reference's), not an added variance: does a
walk example's amplitude change carry to a wave?

- output shaper ``moments_ratio`` (``floor`` as ``moments``): each channel's deviations scaled so that its standard
  deviation is the content's x the example's / the reference's (gain within [1/4, 4], floored at ``floor`` x the
  content's), then the product's posture step;
- output shaper ``posture``: the product's posture step alone, the output's spread left as the steps before set it.

Why: the product's rule adds the example's variance change to the content's; a walk's arm swing is small, so added to a
wave it barely changes it, while a style that halves the swing of a walk plausibly halves a wave. The coordination map
before it is already a gain (whitening-colouring), which the additive rule then undoes channel by channel; ``posture``
keeps the map's gains. Control: ``bench/bench_lso.py run --row shapers --hook-modules lab.style_moments_ratio
--shapers moments_ratio`` (the step alone on the content clip).
"""

from __future__ import annotations

import numpy as np

from motionaug.augment.methods.hooks import OutputShaper, ShapeContext, output_shapers
from motionaug.augment.methods.shapers import AMPLITUDE_MOST, Moments, with_posture
from motionaug.augment.motion.features import feature_slices
from motionaug.schemas.skeleton import T2M


def with_gain(
    output: np.ndarray, content: np.ndarray, example: np.ndarray, reference: np.ndarray, floor: float
) -> np.ndarray:
    """``output`` (T, F) whose root height, pose and joint velocity channels spread as the content's x the example's
    over the reference's standard deviation (the gain within [1 / AMPLITUDE_MOST, AMPLITUDE_MOST])."""
    slices = feature_slices(T2M)
    cols = np.r_[slices["root_y"], slices["ric"], slices["rot"], slices["local_vel"]]
    gain = example[:, cols].std(0) / np.maximum(reference[:, cols].std(0), 1e-6)
    gain = np.clip(gain, 1.0 / AMPLITUDE_MOST, AMPLITUDE_MOST)
    target = np.maximum(content[:, cols].std(0) * gain, floor * content[:, cols].std(0))
    mean = output[:, cols].mean(axis=0)
    scale = target / np.maximum(output[:, cols].std(axis=0), 1e-6)
    out = output.copy()
    out[:, cols] = (mean + (output[:, cols] - mean) * np.minimum(scale, AMPLITUDE_MOST)).astype(np.float32)
    return out


@output_shapers.register("moments_ratio")
class MomentsRatio(Moments):
    """The example's amplitude as a gain over its reference, then its posture (module doc)."""

    def __call__(self, output: np.ndarray, context: ShapeContext) -> np.ndarray:
        if context.reference is None:
            raise ValueError("moments_ratio needs the example's reference")
        output = with_gain(output, context.content, context.example, context.reference, self.floor)
        return with_posture(output, context.content, context.example, context.reference)


@output_shapers.register("posture")
class Posture(OutputShaper):
    """The example's posture over its reference alone (module doc)."""

    needs_reference = True

    def __call__(self, output: np.ndarray, context: ShapeContext) -> np.ndarray:
        if context.reference is None:
            raise ValueError("posture needs the example's reference")
        return with_posture(output, context.content, context.example, context.reference)
