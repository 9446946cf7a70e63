"""The output shapers the shipped configs name, registered in ``hooks.output_shapers``.

``moments``: an output's posture and amplitude taken from the style examples. Each channel's mean and variance
over the output's frames are set to the content's plus the style example's less its reference's (the pool clip
standing in for the example's content performed plainly): the style's second-order statistics (AdaIN's moments,
between the example and its plain stand-in) moved onto the content, the output keeping its own motion.
"""

from __future__ import annotations

import numpy as np

from motionaug.augment.methods.hooks import OutputShaper, ShapeContext, output_shapers
from motionaug.augment.motion.features import feature_slices
from motionaug.schemas.skeleton import T2M

AMPLITUDE_MOST = 4.0  # the largest factor an output channel's deviations are scaled by (near-still channels)


def with_posture(output: np.ndarray, content: np.ndarray, example: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """An output (T, F) whose root height and pose channels' means over frames are the content's + the example's -
    the reference's."""
    slices = feature_slices(T2M)
    pose = np.r_[slices["root_y"], slices["ric"], slices["rot"]]
    target = content[:, pose].mean(axis=0) + example[:, pose].mean(axis=0) - reference[:, pose].mean(0)
    out = output.copy()
    out[:, pose] += (target - output[:, pose].mean(axis=0)).astype(np.float32)
    return out


def with_amplitude(
    output: np.ndarray, content: np.ndarray, example: np.ndarray, reference: np.ndarray, floor: float
) -> np.ndarray:
    """An output (T, F) whose root height, pose and joint velocity channels vary over frames as much as the
    content's + the example's - the reference's variance says, floored at (``floor`` x the content's std)^2."""
    slices = feature_slices(T2M)
    cols = np.r_[slices["root_y"], slices["ric"], slices["rot"], slices["local_vel"]]
    target = content[:, cols].var(0) + example[:, cols].var(0) - reference[:, cols].var(0)
    target = np.maximum(target, floor**2 * content[:, cols].var(axis=0))
    mean = output[:, cols].mean(axis=0)
    scale = np.sqrt(target) / np.maximum(output[:, cols].std(axis=0), 1e-6)
    out = output.copy()
    out[:, cols] = (mean + (output[:, cols] - mean) * np.minimum(scale, AMPLITUDE_MOST)).astype(np.float32)
    return out


@output_shapers.register("moments")
class Moments(OutputShaper):
    """The examples' amplitude, then their posture (module doc); ``floor``: least std of a channel, x the content's."""

    needs_reference = True

    def __init__(self, floor: float = 0.25) -> None:
        if not 0.0 <= floor <= 1.0:
            raise ValueError(f"moments floor {floor} is outside [0, 1]")
        self.floor = floor

    def __call__(self, output: np.ndarray, context: ShapeContext) -> np.ndarray:
        if context.reference is None:
            raise ValueError("the moments shaper needs the example's reference")
        output = with_amplitude(output, context.content, context.example, context.reference, self.floor)
        return with_posture(output, context.content, context.example, context.reference)
