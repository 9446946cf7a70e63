"""A travelling example's body rhythm on a clip that stays in place: can a walk say how a style moves a standing body?

- output shaper ``body_rhythm`` (``gain``, ``source``): on a clip that stays in place, shaped by an example that
  travels, the example's root height and trunk deviations from their means over its frames (the bounce and the
  trunk's sway of its gait), looped to the clip's length and scaled by ``gain``, added to the output: the bounce, below
  the standing height only, lowers the pelvis and everything above the knees, a trunk joint's shift carries the arm
  hanging from it; the knees are left to ``plant_feet`` (two-bone IK to the feet, which stay), the step after it.
  ``source=reference``: the same step with the example's reference (a plain walk's rhythm): its control.

Why: on the Bandai-2 train takes a style's standing actions (waves, raises) move the root height, legs and trunk far
more than the plain ones, where the arms' spread changes less; a plain wave barely moves its body, so no map of its
positions can give it the style's body motion, and a walk example has no wave to take it from. Its gait's rhythm is
the one body motion of the style it shows (lab/NOTES.md 0).
"""

from __future__ import annotations

import numpy as np

from motionaug.augment.methods.hooks import OutputShaper, ShapeContext, output_shapers
from motionaug.augment.motion.features import feature_slices
from motionaug.augment.motion.travel import travels
from motionaug.schemas.skeleton import T2M

TRUNK = (3, 6, 9, 12, 15)  # spine1, spine2, spine3, neck, head
ARMS = {13: (16, 18, 20), 14: (17, 19, 21)}  # collar -> the arm hanging from it
COLLARS = (13, 14)
BELOW_HIPS = (4, 5, 7, 8, 10, 11)  # knees, ankles, feet: they stay where they stand


def rhythm(motion: np.ndarray, frames: int) -> tuple[np.ndarray, np.ndarray]:
    """(frames,) root height drops below its highest and (frames, 22, 3) root-relative joint deviations (trunk and
    collars only, heights taken over the root's), the clip's frames looped from its start."""
    sl = feature_slices(T2M)
    root_y = motion[:, sl["root_y"]][:, 0].astype(np.float64)
    ric = motion[:, sl["ric"]].reshape(len(motion), T2M.n_joints - 1, 3).astype(np.float64)
    joints = np.zeros((len(motion), T2M.n_joints, 3))
    joints[:, 1:] = ric
    joints[:, 1:, 1] -= root_y[:, None]  # heights over the root's: the bounce is root_y's alone
    index = np.arange(frames) % len(motion)
    dy = (root_y - root_y.max())[index]
    dj = np.zeros((frames, T2M.n_joints, 3))
    for j in (*TRUNK, *COLLARS):
        dj[:, j] = (joints[:, j] - joints[:, j].mean(0))[index]
    return dy, dj


@output_shapers.register("body_rhythm")
class BodyRhythm(OutputShaper):
    """A travelling example's bounce and trunk sway on a clip in place (module doc)."""

    needs_reference = True

    def __init__(self, gain: float = 1.0, source: str = "example") -> None:
        if gain < 0 or source not in ("example", "reference"):
            raise ValueError(f"body_rhythm needs gain >= 0 and source example|reference, got {gain}, {source!r}")
        self.gain, self.source = gain, source

    def __call__(self, output: np.ndarray, context: ShapeContext) -> np.ndarray:
        if context.reference is None:
            raise ValueError("body_rhythm needs the example's reference")
        if travels(context.content, context.fps) or not travels(context.example, context.fps):
            return output
        source = context.example if self.source == "example" else context.reference
        dy, dj = rhythm(np.asarray(source), len(output))
        sl = feature_slices(T2M)
        out = output.copy()
        ric = out[:, sl["ric"]].reshape(len(out), T2M.n_joints - 1, 3).astype(np.float64)
        for j in (*TRUNK, *COLLARS):
            ric[:, j - 1] += self.gain * dj[:, j]
        for collar, arm in ARMS.items():
            for j in arm:
                ric[:, j - 1] += self.gain * dj[:, collar]
        above = [j - 1 for j in range(1, T2M.n_joints) if j not in BELOW_HIPS]
        ric[:, above, 1] += self.gain * dy[:, None]
        out[:, sl["ric"]] = ric.reshape(len(out), -1).astype(np.float32)
        out[:, sl["root_y"]] += (self.gain * dy[:, None]).astype(np.float32)
        return out
