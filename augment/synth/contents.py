"""Content definitions: what the body does (walk, kick, wave...) as joint-angle curves over a phase clock.

Each content maps a phase (cycles, already shaped by the style's timing) to local euler angles per
joint, plus what the animator needs to place the body: airborne height, which frames touch the
ground, and how the heading turns. Styles enter only through their amplitude numbers here; posture
and timing are layered on by the animator, so every content accepts every style.

Angle conventions (radians, about the parent's frame; the character faces +Z, left is +X, Y up):
channel 0 = X (pitch), 1 = Y (yaw/twist), 2 = Z (roll/abduction). Helpers below name the signs.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from motionaug.augment.synth.styles import StyleParams

# t2m joint indices (SMPL order)
PELVIS, L_HIP, R_HIP, SPINE1, L_KNEE, R_KNEE, SPINE2, L_ANKLE, R_ANKLE, SPINE3 = range(10)
L_FOOT, R_FOOT, NECK, L_COLLAR, R_COLLAR, HEAD, L_SHOULDER, R_SHOULDER = range(10, 18)
L_ELBOW, R_ELBOW, L_WRIST, R_WRIST = range(18, 22)
X, Y, Z = 0, 1, 2
TAU = 2.0 * np.pi


@dataclass
class ContentContext:
    """Inputs of a content: the phase clock, the style's numbers and the clip's content parameters."""

    phase: np.ndarray  # (T,) cycles, style timing applied
    rate: np.ndarray  # (T,) cycles per second
    fps: float
    style: StyleParams
    amplitude: float  # per-clip amplitude factor (~1)
    speed: float  # per-clip speed factor (~1)
    side: int  # +1 left, -1 right (which limb / which way)
    curvature: float  # rad per metre, walk_curve
    travel: float  # metres per jump, jump

    @property
    def n_frames(self) -> int:
        return int(self.phase.shape[0])


@dataclass
class ContentMotion:
    """A content's output. ``angles`` (T, 22, 3); ``air`` metres above ground contact; ``ground``
    False where both feet are off the floor; ``air_velocity`` (T, 2) body-frame xz metres/s in
    those frames; ``heading_per_metre`` turns the path with distance; ``heading_offset`` (T,)
    turns the body on the spot. ``arm_posture``/``leg_posture`` (T,) scale the style's limb
    posture where the content needs the limb (a fist-up style must not stop a punch extending)."""

    angles: np.ndarray
    air: np.ndarray
    ground: np.ndarray
    air_velocity: np.ndarray
    arm_posture: np.ndarray
    leg_posture: np.ndarray
    heading_per_metre: float = 0.0
    heading_offset: np.ndarray | None = None


def empty_motion(n: int) -> ContentMotion:
    return ContentMotion(
        angles=np.zeros((n, 22, 3)),
        air=np.zeros(n),
        ground=np.ones(n, dtype=bool),
        air_velocity=np.zeros((n, 2)),
        arm_posture=np.ones(n),
        leg_posture=np.ones(n),
    )


def smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def keyframes(u: np.ndarray, knots: list[tuple[float, float]]) -> np.ndarray:
    """Eased interpolation through (u, value) knots on a cycle u in [0, 1); flat outside the knots.

    Eased segments give zero velocity at every knot: strikes start and stop like real gestures.
    """
    ku = np.array([k[0] for k in knots])
    kv = np.array([k[1] for k in knots])
    idx = np.clip(np.searchsorted(ku, u, side="right") - 1, 0, len(ku) - 2)
    span = np.maximum(ku[idx + 1] - ku[idx], 1e-9)
    s = smoothstep((u - ku[idx]) / span)
    out = kv[idx] + s * (kv[idx + 1] - kv[idx])
    out = np.where(u < ku[0], kv[0], out)
    return np.where(u > ku[-1], kv[-1], out)


# --- sign helpers: name the anatomical motion, hide the axis sign -----------------------------


def flex_leg(a: np.ndarray, hip: int, angle: np.ndarray) -> None:
    """Hip flexion: thigh swings forward for positive angles."""
    a[:, hip, X] -= angle


def bend_knee(a: np.ndarray, knee: int, angle: np.ndarray) -> None:
    a[:, knee, X] += angle


def flex_arm(a: np.ndarray, shoulder: int, angle: np.ndarray) -> None:
    """Shoulder flexion: arm swings forward (and up past 90 degrees) for positive angles."""
    a[:, shoulder, X] -= angle


def bend_elbow(a: np.ndarray, elbow: int, angle: np.ndarray) -> None:
    a[:, elbow, X] -= angle


def abduct(a: np.ndarray, joint: int, left: bool, angle: np.ndarray) -> None:
    """Move a limb away from the body's midline (left limbs toward +X, right toward -X)."""
    a[:, joint, Z] += angle if left else -angle


def flat_feet(a: np.ndarray) -> None:
    """Keep the feet level with the floor whatever the hip and knee do (ankle compensates).

    Called once, after style posture, so the ankle channel of a content holds only its extra
    foot pitch (toe-off, pointing a kick).
    """
    for hip, knee, ankle in ((L_HIP, L_KNEE, L_ANKLE), (R_HIP, R_KNEE, R_ANKLE)):
        a[:, ankle, X] = -(a[:, hip, X] + a[:, knee, X]) + a[:, ankle, X]


# --- contents ---------------------------------------------------------------------------------


def _legs_cycle(ctx: ContentContext, phase: np.ndarray, hip_amp: float, knee_amp: float, motion: ContentMotion) -> None:
    """Alternating leg swing: the left leg is forward at phase 0, the right at 0.5."""
    a, st = motion.angles, ctx.style
    for hip, knee, ankle, offset in ((L_HIP, L_KNEE, L_ANKLE, 0.0), (R_HIP, R_KNEE, R_ANKLE, 0.5)):
        w = TAU * (phase + offset)
        swing = np.maximum(0.0, -np.sin(w))
        stance = np.maximum(0.0, np.sin(w))
        march = 0.35 * max(st.knee_lift - 1.0, 0.0) * swing**1.5  # high knees lift the thigh, not just the heel
        flex_leg(a, hip, hip_amp * st.step * ctx.amplitude * np.cos(w) + march)
        bend_knee(a, knee, knee_amp * min(st.knee_lift, 1.4) * swing**1.5 + 0.12 * stance**2)
        a[:, ankle, X] += 0.25 * np.maximum(0.0, np.sin(w - 0.6)) ** 4 - 0.15 * swing


def _arms_swing(ctx: ContentContext, phase: np.ndarray, arm_amp: float, elbow: float, motion: ContentMotion) -> None:
    """Arms swing opposite to the legs."""
    a, st = motion.angles, ctx.style
    for shoulder, elb, offset in ((L_SHOULDER, L_ELBOW, 0.5), (R_SHOULDER, R_ELBOW, 0.0)):
        w = TAU * (phase + offset)
        swing = arm_amp * st.arm_swing * ctx.amplitude * np.cos(w)
        flex_arm(a, shoulder, swing)
        bend_elbow(a, elb, elbow + 0.5 * np.maximum(swing, 0.0))


def _gait(ctx: ContentContext, phase: np.ndarray, hip: float, knee: float, arm: float, elbow: float) -> ContentMotion:
    m = empty_motion(ctx.n_frames)
    _legs_cycle(ctx, phase, hip, knee, m)
    _arms_swing(ctx, phase, arm, elbow, m)
    return m


def walk(ctx: ContentContext) -> ContentMotion:
    return _gait(ctx, ctx.phase, 0.34 * np.sqrt(ctx.speed), 0.65, 0.3, 0.2)


def walk_backward(ctx: ContentContext) -> ContentMotion:
    """Walking backwards is walking with the leg cycle run in reverse."""
    m = _gait(ctx, -ctx.phase, 0.24 * np.sqrt(ctx.speed), 0.6, 0.15, 0.25)
    m.angles[:, NECK, X] += 0.1
    return m


def walk_curve(ctx: ContentContext) -> ContentMotion:
    m = walk(ctx)
    m.heading_per_metre = ctx.side * ctx.curvature
    m.angles[:, SPINE2, Y] += ctx.side * 0.1
    return m


def turn(ctx: ContentContext) -> ContentMotion:
    """Small steps on the spot while the body turns around (90 to 180 degrees, ``travel`` radians)."""
    m = _gait(ctx, ctx.phase, 0.12, 0.7, 0.12, 0.2)
    m.heading_offset = ctx.side * ctx.travel * smoothstep((ctx.phase - ctx.phase[0]) / 2.5)
    return m


def run(ctx: ContentContext) -> ContentMotion:
    m = _gait(ctx, ctx.phase, 0.5 * np.sqrt(ctx.speed), 1.2, 0.55, 1.35)
    m.angles[:, SPINE1, X] += 0.15
    u = np.mod(ctx.phase, 0.5) * 2.0  # leg switches at u = 0
    flight = np.maximum(0.0, np.cos(np.pi * u)) ** 8 + np.maximum(0.0, -np.cos(np.pi * u)) ** 8
    m.air += 0.05 * ctx.style.knee_lift**0.5 * flight
    return m


def sidestep(ctx: ContentContext) -> ContentMotion:
    """Legs abduct alternately; reversing the cycle steps to the other side."""
    m = empty_motion(ctx.n_frames)
    a, st = m.angles, ctx.style
    phase = ctx.phase if ctx.side > 0 else -ctx.phase
    for hip, knee, left, offset in ((L_HIP, L_KNEE, True, 0.0), (R_HIP, R_KNEE, False, 0.5)):
        w = TAU * (phase + offset)
        lateral = 0.14 * st.step * ctx.amplitude * np.cos(w)
        abduct(a, hip, left, 0.1 + (lateral if left else -lateral))
        swing = np.maximum(0.0, -np.sin(w))
        bend_knee(a, knee, 0.6 * st.knee_lift * swing**1.5)
        flex_leg(a, hip, 0.25 * st.knee_lift * swing**1.5)
    for shoulder, left in ((L_SHOULDER, True), (R_SHOULDER, False)):
        abduct(a, shoulder, left, 0.15 + 0.12 * st.arm_swing * np.sin(TAU * phase) ** 2)
    return m


def jump(ctx: ContentContext) -> ContentMotion:
    """Crouch, take off with an arm swing, fly, land in a crouch, stand; ``travel`` metres forward."""
    m = empty_motion(ctx.n_frames)
    a, g = m.angles, min(ctx.style.gesture, 1.3) * ctx.amplitude
    u = np.mod(ctx.phase, 1.0)
    crouch = keyframes(u, [(0.0, 0.0), (0.1, 0.0), (0.3, 1.0), (0.37, 0.0), (0.6, 0.0), (0.68, 0.8), (0.85, 0.0)])
    t_off, t_land = 0.37, 0.6
    s = np.clip((u - t_off) / (t_land - t_off), 0.0, 1.0)
    in_air = (u > t_off) & (u < t_land)
    m.air = np.where(in_air, 0.28 * g * 4.0 * s * (1.0 - s), 0.0)
    m.ground = ~in_air
    tuck = np.where(in_air, np.sin(np.pi * s), 0.0)
    m.air_velocity[:, 1] = np.where(in_air, ctx.travel * g / (t_land - t_off) * ctx.rate, 0.0)
    for hip, knee in ((L_HIP, L_KNEE), (R_HIP, R_KNEE)):
        flex_leg(a, hip, 0.9 * crouch + 0.5 * tuck)
        bend_knee(a, knee, 1.5 * crouch + 0.8 * tuck)
    a[:, SPINE1, X] += 0.45 * crouch
    arm = keyframes(u, [(0.0, 0.0), (0.1, 0.0), (0.3, -0.7), (0.4, 2.4 * min(g, 1.1)), (0.6, 0.8), (0.85, 0.0)])
    for shoulder, elbow in ((L_SHOULDER, L_ELBOW), (R_SHOULDER, R_ELBOW)):
        flex_arm(a, shoulder, arm)
        bend_elbow(a, elbow, 0.3 + 0.2 * crouch)
    return m


def kick(ctx: ContentContext) -> ContentMotion:
    """Chamber the knee, snap the leg out forward, retract, stand."""
    m = empty_motion(ctx.n_frames)
    a, g = m.angles, ctx.style.gesture * ctx.amplitude
    u = np.mod(ctx.phase, 1.0)
    left = ctx.side > 0
    hip, knee = (L_HIP, L_KNEE) if left else (R_HIP, R_KNEE)
    support_knee = R_KNEE if left else L_KNEE
    lift = keyframes(u, [(0.0, 0.0), (0.1, 0.0), (0.28, 0.75), (0.4, 1.35), (0.55, 0.7), (0.7, 0.0)])
    fold = keyframes(u, [(0.0, 0.0), (0.1, 0.0), (0.28, 1.6), (0.4, 0.1), (0.55, 1.4), (0.7, 0.0)])
    flex_leg(a, hip, g * lift)
    bend_knee(a, knee, np.minimum(g, 1.0) * fold)
    m.leg_posture = 1.0 - lift / 1.35
    bend_knee(a, support_knee, 0.15 * lift)
    a[:, SPINE1, X] -= 0.25 * lift * g
    for shoulder, elbow, is_left in ((L_SHOULDER, L_ELBOW, True), (R_SHOULDER, R_ELBOW, False)):
        abduct(a, shoulder, is_left, 0.35 * lift)
        bend_elbow(a, elbow, 0.6 * lift)
    a[:, L_ANKLE if left else R_ANKLE, X] += 0.5 * lift  # point the kicking foot
    return m


def punch(ctx: ContentContext) -> ContentMotion:
    """Guard with fists up; left and right straight punches alternate with a torso twist."""
    m = empty_motion(ctx.n_frames)
    a, g = m.angles, ctx.style.gesture * ctx.amplitude
    u = np.mod(ctx.phase, 1.0)
    lead = 1.0 if ctx.side > 0 else -1.0
    flex_leg(a, L_HIP, np.full_like(u, 0.18 * lead))
    flex_leg(a, R_HIP, np.full_like(u, -0.18 * lead))
    for knee in (L_KNEE, R_KNEE):
        bend_knee(a, knee, np.full_like(u, 0.2))
    knots = [(0.0, 0.0), (0.06, 0.0), (0.16, 1.0), (0.24, 1.0), (0.38, 0.0)]
    m.arm_posture = np.full_like(u, 0.15)
    for shoulder, elbow, left, offset in ((L_SHOULDER, L_ELBOW, True, 0.0), (R_SHOULDER, R_ELBOW, False, 0.5)):
        strike = keyframes(np.mod(u - offset, 1.0), knots)
        flex_arm(a, shoulder, 0.55 + (1.0 * min(g, 1.2)) * strike)
        bend_elbow(a, elbow, 2.1 - 2.0 * strike)
        abduct(a, shoulder, left, 0.25 - 0.2 * strike)
        a[:, SPINE2, Y] += (-0.35 if left else 0.35) * g * strike
    return m


def wave(ctx: ContentContext) -> ContentMotion:
    """Raise one arm with the forearm up, wave the hand side to side, lower it."""
    m = empty_motion(ctx.n_frames)
    a, g = m.angles, ctx.style.gesture * ctx.amplitude
    u = np.mod(ctx.phase, 1.0)
    left = ctx.side > 0
    shoulder, elbow = (L_SHOULDER, L_ELBOW) if left else (R_SHOULDER, R_ELBOW)
    up = keyframes(u, [(0.0, 0.0), (0.05, 0.0), (0.2, 1.0), (0.8, 1.0), (0.95, 0.0)])
    waving = keyframes(u, [(0.0, 0.0), (0.18, 0.0), (0.25, 1.0), (0.75, 1.0), (0.82, 0.0)])
    m.arm_posture = 1.0 - 0.8 * up
    abduct(a, shoulder, left, (1.0 + 0.35 * min(g, 1.3)) * up)
    flex_arm(a, shoulder, 0.35 * up)
    a[:, elbow, Z] += (1.0 if left else -1.0) * (1.3 * up + 0.4 * min(g, 1.4) * waving * np.sin(TAU * 6.0 * ctx.phase))
    a[:, NECK, Y] += (0.2 if left else -0.2) * up
    return m


def raise_hands(ctx: ContentContext) -> ContentMotion:
    """Both arms go up overhead, hold, come down."""
    m = empty_motion(ctx.n_frames)
    a, g = m.angles, ctx.style.gesture * ctx.amplitude
    u = np.mod(ctx.phase, 1.0)
    up = keyframes(u, [(0.0, 0.0), (0.05, 0.0), (0.3, 1.0), (0.6, 1.0), (0.85, 0.0)])
    height = min(2.2 + 0.6 * g, 3.0)
    m.arm_posture = 1.0 - 0.8 * up
    for shoulder, elbow, left in ((L_SHOULDER, L_ELBOW, True), (R_SHOULDER, R_ELBOW, False)):
        flex_arm(a, shoulder, height * up)
        abduct(a, shoulder, left, 0.25 * up)
        bend_elbow(a, elbow, 0.15 * up)
    a[:, NECK, X] -= 0.2 * up
    return m


def squat(ctx: ContentContext) -> ContentMotion:
    """Bend hips and knees with the arms forward for balance, then stand up."""
    m = empty_motion(ctx.n_frames)
    a, g = m.angles, min(0.6 + 0.4 * ctx.style.gesture * ctx.amplitude, 1.15)
    u = np.mod(ctx.phase, 1.0)
    down = keyframes(u, [(0.0, 0.0), (0.05, 0.0), (0.4, 1.0), (0.55, 1.0), (0.9, 0.0)])
    for hip, knee, left in ((L_HIP, L_KNEE, True), (R_HIP, R_KNEE, False)):
        flex_leg(a, hip, 1.4 * g * down)
        bend_knee(a, knee, 1.8 * g * down)
        abduct(a, hip, left, 0.12 + 0.1 * down)
    a[:, SPINE1, X] += 0.45 * g * down
    for shoulder in (L_SHOULDER, R_SHOULDER):
        flex_arm(a, shoulder, 1.3 * down)
    return m


@dataclass(frozen=True)
class ContentDef:
    """A content: its animation function, base cycle rate (Hz) and clip length range (s)."""

    fn: Callable[[ContentContext], ContentMotion]
    rate: float
    duration: tuple[float, float]
    locomotion: bool


CONTENTS: dict[str, ContentDef] = {
    "walk": ContentDef(walk, 0.95, (3.0, 8.0), True),
    "run": ContentDef(run, 1.35, (2.0, 6.0), True),
    "walk_backward": ContentDef(walk_backward, 0.85, (3.0, 7.0), True),
    "walk_curve": ContentDef(walk_curve, 0.95, (4.0, 8.0), True),
    "sidestep": ContentDef(sidestep, 0.8, (3.0, 7.0), True),
    "turn": ContentDef(turn, 0.9, (4.0, 7.0), True),
    "jump": ContentDef(jump, 0.6, (3.0, 7.0), False),
    "kick": ContentDef(kick, 0.55, (3.0, 7.0), False),
    "punch": ContentDef(punch, 0.75, (2.5, 6.0), False),
    "wave": ContentDef(wave, 0.33, (3.0, 7.0), False),
    "raise_hands": ContentDef(raise_hands, 0.4, (3.0, 7.0), False),
    "squat": ContentDef(squat, 0.45, (3.0, 7.0), False),
}
