"""Parametric animator: a ``ClipSpec`` becomes joint positions (T, 22, 3) on the t2m skeleton.

Pipeline: phase clock (style timing) -> content joint angles -> style posture overlay -> forward
kinematics in the body frame -> feet on the floor (root height from the lowest foot) -> root path
from the stance foot (so planted feet do not skate) -> world heading. Everything derives from the
spec, so ``render(spec.with_style(s))`` is the same content, path shape, duration and bones in
another style: paired ground truth for style transfer.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from motionaug.augment.synth import contents as C
from motionaug.augment.synth.contents import CONTENTS, ContentContext, ContentMotion
from motionaug.augment.synth.styles import STYLES, StyleParams, style_params
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import T2M

FPS = 20.0

# Bone lengths (metres, parent -> joint) from HumanML3D's reference skeleton clip joints/000021.npy
# frame 0, first 22 joints (HumanML3D's reference skeleton), left/right averaged so mirrors agree.
BONE_LENGTHS = np.array(
    [
        0.0,
        0.1065,
        0.1065,
        0.1316,
        0.3919,
        0.3919,
        0.1432,
        0.4290,
        0.4290,
        0.0574,
        0.1464,
        0.1464,
        0.2194,
        0.1405,
        0.1405,
        0.1030,
        0.1273,
        0.1273,
        0.2600,
        0.2600,
        0.2680,
        0.2680,
    ]
)

# Anatomical rest directions (unit, body frame). T2M.raw_offsets only name the axis each bone is
# measured along; real bodies have hips below-outside the pelvis, collars rising to the shoulders,
# the head above the neck and the toes below the ankle, which this rest pose keeps.
_REST = np.array(
    [
        (0, 0, 0),
        (0.6, -0.8, 0),
        (-0.6, -0.8, 0),
        (0, 1, -0.1),
        (0, -1, 0),
        (0, -1, 0),
        (0, 1, 0),
        (0, -1, 0),
        (0, -1, 0),
        (0, 1, 0),
        (0, -0.35, 0.94),
        (0, -0.35, 0.94),
        (0, 1, 0.05),
        (0.5, 0.85, 0),
        (-0.5, 0.85, 0),
        (0, 0.87, 0.5),
        (1, -0.1, 0),
        (-1, -0.1, 0),
        (0, -1, 0),
        (0, -1, 0),
        (0, -1, 0),
        (0, -1, 0),
    ],
    dtype=float,
)
REST_DIRECTIONS = _REST / np.maximum(np.linalg.norm(_REST, axis=1, keepdims=True), 1e-9)
PARENTS = tuple(T2M.parents)
FOOT_JOINTS = (C.L_ANKLE, C.R_ANKLE, C.L_FOOT, C.R_FOOT)
_MIRROR_BONES = dict(T2M.mirror_pairs) | {b: a for a, b in T2M.mirror_pairs}


class ClipSpec(BaseModel):
    """Everything that defines one synthetic clip; JSON-serialisable so a corpus can re-render it.

    ``bone_scale`` multiplies each parent->joint bone (22 values, index 0 unused).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    version: int = 1
    content: str
    style: str = "neutral"
    intensity: float = Field(1.0, ge=0.0, le=1.5)
    seed: int = 0
    duration: float = Field(4.0, ge=1.0, le=12.0)
    fps: float = FPS
    speed: float = Field(1.0, gt=0.3, lt=3.0)
    amplitude: float = Field(1.0, gt=0.3, lt=3.0)
    phase: float = 0.0
    heading: float = 0.0
    side: Literal["left", "right"] = "left"
    curvature: float = 0.6
    travel: float = 0.0
    bone_scale: tuple[float, ...] = Field(default=(1.0,) * 22, min_length=22, max_length=22)

    @field_validator("content")
    @classmethod
    def _known_content(cls, v: str) -> str:
        if v not in CONTENTS:
            raise ValueError(f"unknown content {v!r}; known: {sorted(CONTENTS)}")
        return v

    @field_validator("style")
    @classmethod
    def _known_style(cls, v: str) -> str:
        if v not in STYLES:
            raise ValueError(f"unknown style {v!r}; known: {sorted(STYLES)}")
        return v

    @property
    def n_frames(self) -> int:
        return int(round(self.duration * self.fps))

    def with_style(self, style: str, intensity: float | None = None) -> ClipSpec:
        """The same content (path, duration, bones, phase) in another style."""
        return self.model_validate(
            self.model_dump() | {"style": style, "intensity": self.intensity if intensity is None else intensity}
        )

    def to_json(self) -> str:
        return self.model_dump_json()

    @classmethod
    def from_json(cls, text: str) -> ClipSpec:
        try:
            return cls.model_validate(json.loads(text))
        except (ValueError, TypeError) as err:
            raise MotionDataError("clip spec", f"cannot parse: {err}".splitlines()[0]) from None


def sample_spec(rng: np.random.Generator, content: str, style: str = "neutral", seed: int | None = None) -> ClipSpec:
    """Random content parameters (speed, amplitude, phase, heading, duration, bones) for one clip."""
    cdef = CONTENTS[content]
    lo, hi = cdef.duration
    body = float(rng.uniform(0.95, 1.05))
    jitter = rng.uniform(0.98, 1.02, size=22)
    scale = [body * float(0.5 * (jitter[j] + jitter[_MIRROR_BONES.get(j, j)])) for j in range(22)]
    scale[0] = 1.0
    travel = {"jump": float(rng.choice([0.0, rng.uniform(0.4, 0.8)])), "turn": float(rng.uniform(1.6, 3.14))}
    return ClipSpec(
        content=content,
        style=style,
        intensity=float(rng.uniform(0.8, 1.0)) if style != "neutral" else 1.0,
        seed=int(rng.integers(0, 2**31 - 1)) if seed is None else seed,
        duration=round(float(rng.uniform(lo, hi)) * FPS) / FPS,
        speed=float(rng.uniform(0.85, 1.15)),
        amplitude=float(rng.uniform(0.88, 1.12)),
        phase=float(rng.uniform(0.0, 1.0)) if cdef.locomotion else float(rng.uniform(0.0, 0.05)),
        heading=float(rng.uniform(-np.pi, np.pi)),
        side=str(rng.choice(["left", "right"])),
        curvature=float(rng.uniform(0.35, 0.8)),
        travel=travel.get(content, 0.0),
        bone_scale=tuple(scale),
    )


@dataclass
class RenderedClip:
    """Joint positions (T, 22, 3) float32 in metres, floor at y = 0, plus the facing per frame."""

    spec: ClipSpec
    joints: np.ndarray
    heading: np.ndarray  # (T,) radians; 0 faces +Z, positive turns toward +X (the body's left)
    ground: np.ndarray  # (T,) bool, some foot on the floor


# --- rotations and forward kinematics ---------------------------------------------------------


def _axis_rotation(angle: np.ndarray, axis: int) -> np.ndarray:
    """(..., 3, 3) right-handed rotations about one axis."""
    c, s = np.cos(angle), np.sin(angle)
    m = np.zeros(angle.shape + (3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    m[..., axis, axis] = 1.0
    m[..., i, i], m[..., j, j] = c, c
    m[..., i, j], m[..., j, i] = -s, s
    return m


def euler_to_matrix(angles: np.ndarray) -> np.ndarray:
    """(..., 3) angles (x, y, z) -> (..., 3, 3) as Ry @ Rz @ Rx: twist outermost, flexion innermost."""
    return _axis_rotation(angles[..., 1], 1) @ _axis_rotation(angles[..., 2], 2) @ _axis_rotation(angles[..., 0], 0)


def bone_offsets(bone_scale: tuple[float, ...] | np.ndarray) -> np.ndarray:
    """(22, 3) parent->joint offsets for a spec's bone scale."""
    return REST_DIRECTIONS * (BONE_LENGTHS * np.asarray(bone_scale, dtype=float))[:, None]


def forward_kinematics(angles: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Local euler angles (T, 22, 3) -> joint positions (T, 22, 3) with the root at the origin."""
    local = euler_to_matrix(angles)
    n = angles.shape[0]
    glob = np.empty_like(local)
    pos = np.zeros((n, 22, 3))
    glob[:, 0] = local[:, 0]
    for j in range(1, 22):
        p = PARENTS[j]
        pos[:, j] = pos[:, p] + glob[:, p] @ offsets[j]
        glob[:, j] = glob[:, p] @ local[:, j]
    return pos


# --- timing and style overlay -----------------------------------------------------------------


def phase_clock(spec: ClipSpec, st: StyleParams) -> tuple[np.ndarray, np.ndarray]:
    """Phase (cycles) and its rate per frame: tempo, periodic hesitations and a sharpness warp."""
    cdef = CONTENTS[spec.content]
    t = np.arange(spec.n_frames) / spec.fps
    speed_tempo = np.sqrt(spec.speed) if cdef.locomotion else 1.0
    dip = (0.5 + 0.5 * np.cos(2.0 * np.pi * (t / st.hesitation_period + spec.phase))) ** 6
    rate = cdef.rate * speed_tempo * st.tempo * (1.0 - st.hesitation * dip)
    phase = spec.phase + np.concatenate([[0.0], np.cumsum(rate[:-1]) / spec.fps])
    warped = phase - st.sharpness * np.sin(4.0 * np.pi * phase) / (4.0 * np.pi)
    return warped, rate


def apply_posture(m: ContentMotion, st: StyleParams, phase: np.ndarray, rng: np.random.Generator) -> None:
    """Add the style's posture offsets and rhythmic overlays (sway, swagger, bob) to a content."""
    a = m.angles
    jit = rng.normal(0.0, 0.035, size=6)  # per-clip idiosyncrasy, shared by every style of the clip
    for spine, share in ((C.SPINE1, 0.4), (C.SPINE2, 0.35), (C.SPINE3, 0.25)):
        a[:, spine, C.X] += share * (st.spine_lean + jit[0])
    a[:, C.SPINE3, C.X] += st.chest
    a[:, C.NECK, C.X] += st.head_pitch + jit[1] - 0.5 * (st.spine_lean + st.chest)
    a[:, C.NECK, C.Z] += st.head_roll
    a[:, C.NECK, C.X] += st.head_bob * np.sin(4.0 * np.pi * phase)
    for collar, left in ((C.L_COLLAR, True), (C.R_COLLAR, False)):
        C.abduct(a, collar, left, np.full(len(phase), st.shrug + jit[2]))
        a[:, collar, C.Y] += (-1.0 if left else 1.0) * (st.shoulders_forward + jit[3])
    arm, leg = m.arm_posture, m.leg_posture
    for shoulder, elbow, left in ((C.L_SHOULDER, C.L_ELBOW, True), (C.R_SHOULDER, C.R_ELBOW, False)):
        C.abduct(a, shoulder, left, 0.08 + arm * (st.arm_out + jit[4]))
        C.flex_arm(a, shoulder, arm * st.arm_forward)
        C.bend_elbow(a, elbow, arm * (st.elbow_bend + jit[5]))
    bob = 6.0 * st.bounce * (0.5 + 0.5 * np.cos(4.0 * np.pi * phase))
    for hip, knee, left in ((C.L_HIP, C.L_KNEE, True), (C.R_HIP, C.R_KNEE, False)):
        C.flex_leg(a, hip, leg * (st.hip_bend + 0.5 * st.knee_bend) + 0.5 * bob)
        C.bend_knee(a, knee, leg * st.knee_bend + bob)
        C.abduct(a, hip, left, np.full(len(phase), st.stance_width))
    roll = st.sway * np.sin(2.0 * np.pi * phase)
    a[:, C.PELVIS, C.Z] += roll
    for hip in (C.L_HIP, C.R_HIP):
        a[:, hip, C.Z] -= 1.5 * roll  # -1.0 keeps the legs vertical, the extra -0.5 shifts the pelvis sideways
    a[:, C.SPINE1, C.Z] -= 0.8 * roll
    a[:, C.SPINE2, C.Y] += st.swagger * np.cos(2.0 * np.pi * phase)


# --- placing the body in the world ------------------------------------------------------------


def _root_height(body: np.ndarray, m: ContentMotion) -> np.ndarray:
    """Root height that puts the lowest foot joint on the floor; bridged linearly over flights."""
    contact = -body[:, FOOT_JOINTS, 1].min(axis=1)
    idx = np.arange(len(contact))
    if m.ground.any() and not m.ground.all():
        contact = np.maximum(contact, np.interp(idx, idx[m.ground], contact[m.ground]))
    return contact + m.air


def _stance_weights(body: np.ndarray, m: ContentMotion) -> np.ndarray:
    """(T, 2) soft weights of the left/right foot bearing weight (the lower one wins)."""
    left = body[:, [C.L_ANKLE, C.L_FOOT], 1].min(axis=1)
    right = body[:, [C.R_ANKLE, C.R_FOOT], 1].min(axis=1)
    w_left = 1.0 / (1.0 + np.exp(np.clip((left - right) / 0.008, -50.0, 50.0)))
    return np.stack([w_left, 1.0 - w_left], axis=1) * m.ground[:, None]


def _yaw(h: np.ndarray) -> np.ndarray:
    """(T, 2, 2) rotation of body-frame (x, z) into world (x, z) for headings h."""
    c, s = np.cos(h), np.sin(h)
    return np.stack([np.stack([c, s], -1), np.stack([-s, c], -1)], -2)


def _root_path(body: np.ndarray, m: ContentMotion, spec: ClipSpec) -> tuple[np.ndarray, np.ndarray]:
    """World root xz (T, 2) and heading (T,) such that the stance foot stays where it was planted.

    The body-frame displacement of the planted foot, reversed, is the root's step; flights use the
    content's air velocity. Heading turns with distance walked (curves) or on the spot (turns).
    """
    dt = 1.0 / spec.fps
    feet = body[:, [C.L_FOOT, C.R_FOOT]][:, :, [0, 2]]  # (T, 2 feet, xz)
    w = _stance_weights(body, m)[:-1]  # (T-1, 2)
    step_body = -(w[:, :, None] * (feet[1:] - feet[:-1])).sum(axis=1)
    air = ~m.ground[:-1]
    step_body[air] = m.air_velocity[:-1][air] * dt
    dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(step_body, axis=1))])
    heading = spec.heading + m.heading_per_metre * dist
    if m.heading_offset is not None:
        heading = heading + m.heading_offset
    rot = _yaw(heading)
    foot_world_now = np.einsum("tij,tfj->tfi", rot[:-1], feet[:-1])
    foot_world_next = np.einsum("tij,tfj->tfi", rot[1:], feet[1:])
    step = (w[:, :, None] * (foot_world_now - foot_world_next)).sum(axis=1)
    step[air] = np.einsum("tij,tj->ti", rot[:-1][air], m.air_velocity[:-1][air] * dt)
    root = np.concatenate([np.zeros((1, 2)), np.cumsum(step, axis=0)])
    return root, heading


def content_motion(spec: ClipSpec, style: StyleParams | None = None) -> tuple[ContentMotion, np.ndarray]:
    """Joint angles for a spec (content + style posture + flat feet) and the phase clock.

    ``style`` replaces the spec's style numbers (e.g. a style without its timing changes)."""
    st = style or style_params(spec.style, spec.intensity)
    phase, rate = phase_clock(spec, st)
    ctx = ContentContext(
        phase=phase,
        rate=rate,
        fps=spec.fps,
        style=st,
        amplitude=spec.amplitude,
        speed=spec.speed,
        side=1 if spec.side == "left" else -1,
        curvature=spec.curvature,
        travel=spec.travel,
    )
    m = CONTENTS[spec.content].fn(ctx)
    apply_posture(m, st, phase, np.random.default_rng(spec.seed))
    C.flat_feet(m.angles)
    return m, phase


def render(spec: ClipSpec, style: StyleParams | None = None) -> RenderedClip:
    """Render a spec to world joint positions (float32, floor at y = 0); ``style`` overrides its style numbers."""
    m, _ = content_motion(spec, style)
    body = forward_kinematics(m.angles, bone_offsets(spec.bone_scale))
    height = _root_height(body, m)
    root_xz, heading = _root_path(body, m, spec)
    rot = _yaw(heading)
    xz = np.einsum("tij,tkj->tki", rot, body[:, :, [0, 2]]) + root_xz[:, None, :]
    joints = np.stack([xz[..., 0], body[:, :, 1] + height[:, None], xz[..., 1]], axis=-1)
    if not np.isfinite(joints).all():
        raise MotionDataError(f"synth clip {spec.content}/{spec.style}", "rendering produced non-finite joints")
    on_floor = m.ground & (m.air <= 1e-6)  # running flight keeps the stance path but leaves the floor
    return RenderedClip(spec=spec, joints=joints.astype(np.float32), heading=heading, ground=on_floor)
