"""Style definitions: how each style bends posture, timing and amplitude, and the words that name it.

A style is a small set of numbers layered over any content, so every (content, style) pair exists
and a clip can be re-rendered in another style with the same content parameters (paired ground
truth). ``docs/synthetic-corpus.md`` describes each style in words.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.styles import StyleWords


@dataclass(frozen=True)
class StyleParams:
    """Numbers a style sets. Angles in radians, lengths in metres; neutral is all zeros / ones.

    Posture values are offsets added to every frame; amplitude values scale the content's own
    motion; timing values change the phase clock (tempo, hesitations, sharpness) and add bounce.
    """

    # posture
    spine_lean: float = 0.0  # forward lean of the whole spine (+ forward)
    chest: float = 0.0  # upper-spine pitch (+ slump forward, - chest out)
    head_pitch: float = 0.0  # (+ looks down)
    head_roll: float = 0.0  # sideways head tilt
    shrug: float = 0.0  # collar elevation (+ shoulders up)
    shoulders_forward: float = 0.0  # collar protraction (+ rounded shoulders, - pulled back)
    arm_out: float = 0.0  # arm abduction away from the body
    arm_forward: float = 0.0  # arms carried in front (+)
    elbow_bend: float = 0.0  # extra elbow flexion (fists up)
    knee_bend: float = 0.0  # bent knees throughout
    hip_bend: float = 0.0  # hip flexion throughout (crouch / stoop)
    stance_width: float = 0.0  # leg abduction
    # amplitude
    step: float = 1.0  # leg swing / step length
    arm_swing: float = 1.0
    knee_lift: float = 1.0
    gesture: float = 1.0  # size of kicks, punches, waves, jumps
    # timing
    tempo: float = 1.0  # phase-rate multiplier
    hesitation: float = 0.0  # 0..0.9: depth of periodic slow-downs
    hesitation_period: float = 1.6  # seconds between slow-downs
    sharpness: float = 0.0  # 0..0.9: snappy phase warp (fast strikes, held extremes)
    bounce: float = 0.0  # vertical bob at twice the step rate (metres)
    sway: float = 0.0  # pelvis roll at the step rate (hip sway)
    swagger: float = 0.0  # torso/shoulder yaw swing at the step rate
    head_bob: float = 0.0  # head nod at twice the step rate


NEUTRAL = StyleParams()

STYLES: dict[str, StyleParams] = {
    "neutral": NEUTRAL,
    "proud": StyleParams(
        spine_lean=-0.10,
        chest=-0.22,
        head_pitch=-0.30,
        shoulders_forward=-0.30,
        arm_out=0.22,
        step=1.15,
        arm_swing=1.5,
        knee_lift=1.0,
        gesture=1.1,
        tempo=0.82,
        swagger=0.05,
    ),
    "depressed": StyleParams(
        spine_lean=0.12,
        chest=0.42,
        head_pitch=0.75,
        shoulders_forward=0.25,
        shrug=-0.10,
        arm_out=0.05,
        step=0.5,
        arm_swing=0.15,
        knee_lift=0.5,
        gesture=0.55,
        tempo=0.62,
        hesitation=0.35,
        hesitation_period=2.1,
    ),
    "old": StyleParams(
        spine_lean=0.38,
        chest=0.12,
        head_pitch=-0.25,
        shoulders_forward=0.12,
        arm_forward=0.30,
        elbow_bend=0.55,
        knee_bend=0.55,
        hip_bend=0.22,
        stance_width=0.10,
        step=0.45,
        arm_swing=0.35,
        knee_lift=0.4,
        gesture=0.6,
        tempo=0.7,
        hesitation=0.5,
        hesitation_period=1.3,
    ),
    "childlike": StyleParams(
        spine_lean=0.0,
        head_pitch=-0.08,
        head_roll=0.10,
        arm_out=0.25,
        elbow_bend=0.2,
        step=1.25,
        arm_swing=2.2,
        knee_lift=1.5,
        gesture=1.35,
        tempo=1.45,
        bounce=0.045,
        head_bob=0.12,
    ),
    "angry": StyleParams(
        spine_lean=0.28,
        chest=0.05,
        head_pitch=0.20,
        shrug=0.25,
        shoulders_forward=0.15,
        arm_out=0.30,
        elbow_bend=1.25,
        arm_forward=0.25,
        step=1.2,
        arm_swing=1.3,
        knee_lift=1.5,
        gesture=1.3,
        tempo=1.28,
        sharpness=0.75,
    ),
    "strutting": StyleParams(
        spine_lean=-0.15,
        chest=-0.08,
        head_pitch=-0.12,
        head_roll=-0.12,
        shoulders_forward=-0.12,
        arm_out=0.12,
        step=1.15,
        arm_swing=1.6,
        knee_lift=1.1,
        gesture=1.1,
        tempo=0.95,
        sway=0.22,
        swagger=0.32,
        head_bob=0.10,
    ),
    "sneaky": StyleParams(
        spine_lean=0.35,
        head_pitch=-0.30,
        shrug=0.15,
        arm_forward=0.55,
        elbow_bend=1.5,
        knee_bend=0.7,
        hip_bend=0.3,
        step=1.1,
        arm_swing=0.2,
        knee_lift=1.25,
        gesture=0.75,
        tempo=0.6,
        hesitation=0.6,
        hesitation_period=1.8,
    ),
}

_MULTIPLICATIVE = {"step", "arm_swing", "knee_lift", "gesture", "tempo"}


def style_params(style: str, intensity: float = 1.0) -> StyleParams:
    """The style's numbers blended from neutral by ``intensity`` (0 = neutral, 1 = full style).

    Scales and tempo blend geometrically so half a slow-down is a ratio, not a difference.
    """
    if style not in STYLES:
        raise MotionDataError(f"style {style!r}", f"unknown style; known: {sorted(STYLES)}")
    if not 0.0 <= intensity <= 1.5:
        raise MotionDataError(f"style {style!r}", f"intensity {intensity} outside [0, 1.5]")
    full = STYLES[style]
    blended = {}
    for f in fields(StyleParams):
        a, b = getattr(NEUTRAL, f.name), getattr(full, f.name)
        if f.name in _MULTIPLICATIVE:
            blended[f.name] = a * math.exp(intensity * math.log(b / a))
        elif f.name == "hesitation_period":
            blended[f.name] = b
        else:
            blended[f.name] = a + intensity * (b - a)
    return replace(NEUTRAL, **blended)


STYLE_WORDS: dict[str, StyleWords] = {
    "proud": StyleWords(
        adjective="proud", adverb="proudly", phrases=("in a proud way", "with pride", "with the chest out")
    ),
    "depressed": StyleWords(
        adjective="depressed",
        adverb="sadly",
        phrases=("in a depressed way", "like a sad person", "with the head hanging down"),
    ),
    "old": StyleWords(
        adjective="old", adverb=None, phrases=("like an old person", "like an old man", "in an elderly way")
    ),
    "childlike": StyleWords(
        adjective="childlike", adverb="playfully", phrases=("like a child", "in a childlike way", "like a little kid")
    ),
    "angry": StyleWords(
        adjective="angry", adverb="angrily", phrases=("in an angry way", "like an angry person", "with anger")
    ),
    "strutting": StyleWords(
        adjective="strutting", adverb="confidently", phrases=("with a strut", "with a swagger", "in a strutting way")
    ),
    "sneaky": StyleWords(
        adjective="sneaky", adverb="sneakily", phrases=("in a sneaky way", "like a thief", "on tiptoe sneakily")
    ),
}
