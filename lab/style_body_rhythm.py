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

Why: on the Bandai-2 train takes a style's standing actions (waves, raises) move the root height, legs and trunk far
more than the plain ones, where the arms' spread changes less; a plain wave barely moves its body, so no map of its
positions can give it the style's body motion. A walk example's gait rhythm is the one body motion of the style it
shows; a wave example shows the standing one (lab/NOTES.md 0).
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


def _highpass(x: np.ndarray, width: int) -> np.ndarray:
    """``x`` (T, ...) less its centred moving average over ``width`` frames (edges padded): the drift gone."""
    if width < 2:
        return x
    pad = np.concatenate([np.repeat(x[:1], width // 2, 0), x, np.repeat(x[-1:], width - 1 - width // 2, 0)])
    kernel = np.ones(width) / width
    smooth = np.apply_along_axis(lambda v: np.convolve(v, kernel, mode="valid"), 0, pad)
    return x - smooth


def rhythm(motion: np.ndarray, frames: int, highpass: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(frames,) root height drops below its highest and (frames, 22, 3) root-relative joint deviations (trunk and
    collars only, heights taken over the root's), the clip's frames looped from its start; ``highpass`` > 1: each
    less its moving average over that many frames first (a take's slow drift would loop as a saw)."""
    sl = feature_slices(T2M)
    root_y = motion[:, sl["root_y"]][:, 0].astype(np.float64)
    ric = motion[:, sl["ric"]].reshape(len(motion), T2M.n_joints - 1, 3).astype(np.float64)
    joints = np.zeros((len(motion), T2M.n_joints, 3))
    joints[:, 1:] = ric
    joints[:, 1:, 1] -= root_y[:, None]  # heights over the root's: the bounce is root_y's alone
    root_y, joints = _highpass(root_y, highpass), _highpass(joints, highpass)
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
        source = context.example if self.source == "example" else context.reference
        dy, dj = rhythm(np.asarray(source), len(output), round(self.highpass_s * context.fps))
        if self.excess:  # only the variance the reference lacks: sqrt(1 - var_ref / var_ex) per channel
            ry, rj = rhythm(np.asarray(context.reference), len(output), round(self.highpass_s * context.fps))
            dy = dy * np.sqrt(np.clip(1.0 - ry.var() / max(dy.var(), 1e-12), 0.0, 1.0))
            dj = dj * np.sqrt(np.clip(1.0 - rj.var(0) / np.maximum(dj.var(0), 1e-12), 0.0, 1.0))
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
