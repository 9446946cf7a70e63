"""The output shapers the shipped configs name (``hooks.output_shapers``): post-processes of a transfer's output that
read the content and, where they need one, the style example and its reference (a pool clip: the example's content done
plainly). Style-ERD's configs chain ``STYLE_ERD_CHAIN``.

- ``match_tempo``: the output, and for the later steps the content and reference, at the example's cycle rate;
- ``moments``: posture and amplitude over the reference (AdaIN); ``coordination``: joint covariance (whitening and
  colouring), over time lags where ``taps`` > 0, positions or bones; ``bone_lengths``: the content's bones back;
- ``lock_feet``: the root moved so a planted foot stays put; ``plant_feet``: planted toes held, swing clearance kept;
- ``in_place_rhythm``: an in-place example's body bounce and trunk sway, what its reference lacks, on clips in place.
Each step chosen on an LSO fold 1 val split against its control (``bench/RESULTS.md`` 0)."""

from __future__ import annotations

import hashlib

import numpy as np

from motionaug.augment.methods.hooks import HookSpec, OutputShaper, ShapeContext, output_shapers
from motionaug.augment.metrics import foot_contacts_from_features
from motionaug.augment.motion.features import feature_slices, features_to_joints
from motionaug.augment.motion.foot_lock import lock_feet, plant_feet
from motionaug.augment.motion.tempo import retime, style_tempo
from motionaug.augment.motion.travel import opposed, travels
from motionaug.schemas.skeleton import T2M

STYLE_ERD_CHAIN: tuple[HookSpec, ...] = (
    "match_tempo",
    {"name": "coordination", "lag": 3, "taps": 6},
    "moments",
    "bone_lengths",
    "lock_feet",
    "in_place_rhythm",
    "plant_feet",
)
"""The output shapers both Style-ERD configs and the demo chain after the network (module doc)."""
FLIGHT_APART = 0.2  # a larger gap in the share of frames with no foot down: a walk against a run, not a tempo
MAPS_KEPT = 16  # coordination maps a shaper keeps (one per example and reference it has met)
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
    """The examples' amplitude, then their posture; ``floor``: least std of a channel, x the content's.

    Each channel's mean and variance over the output's frames are set to the content's plus the style example's
    less its reference's: the style's second-order statistics (AdaIN's moments, between the example and its plain
    stand-in) moved onto the content, the output keeping its own motion.
    """

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


def position_channels() -> np.ndarray:
    """Root height and the root-relative joint positions of the HumanML3D features."""
    slices = feature_slices(T2M)
    return np.r_[slices["root_y"], slices["ric"]]


BONES = tuple((parent, child) for chain in T2M.kinematic_chain for parent, child in zip(chain[:-1], chain[1:]))
"""The skeleton's bones as (parent joint, child joint), down each kinematic chain in turn."""
BASES = ("positions", "bones")


def root_relative_joints(features: np.ndarray) -> np.ndarray:
    """(T, J, 3) float64: the root at (0, root height, 0), the other joints from ``ric`` (facing frame)."""
    slices = feature_slices(T2M)
    joints = np.zeros((len(features), T2M.n_joints, 3))
    joints[:, 0, 1] = features[:, slices["root_y"]][:, 0]
    joints[:, 1:] = features[:, slices["ric"]].reshape(len(features), T2M.n_joints - 1, 3)
    return joints


def bone_channels(features: np.ndarray) -> np.ndarray:
    """(T, 1 + 3 x bones) float64: the root height, then each bone's vector (child joint less parent joint)."""
    joints = root_relative_joints(features)
    bones = np.stack([joints[:, child] - joints[:, parent] for parent, child in BONES], axis=1)
    return np.concatenate([joints[:, 0, 1:2], bones.reshape(len(features), -1)], axis=1)


def with_bone_channels(features: np.ndarray, channels: np.ndarray) -> np.ndarray:
    """``features`` (T, F) with the root height and the joints rebuilt down the chains from ``bone_channels``."""
    slices = feature_slices(T2M)
    bones = channels[:, 1:].reshape(len(features), len(BONES), 3)
    joints = np.zeros((len(features), T2M.n_joints, 3))
    joints[:, 0, 1] = channels[:, 0]
    for n, (parent, child) in enumerate(BONES):
        joints[:, child] = joints[:, parent] + bones[:, n]
    out = features.copy()
    out[:, slices["root_y"]] = channels[:, :1].astype(np.float32)
    out[:, slices["ric"]] = joints[:, 1:].reshape(len(features), -1).astype(np.float32)
    return out


def _covariance(x: np.ndarray, shrink: float) -> np.ndarray:
    d = x - x.mean(0)
    cov = d.T @ d / max(len(x) - 1, 1)
    return (1.0 - shrink) * cov + shrink * np.diag(np.diag(cov))


def _power(cov: np.ndarray, exponent: float, floor: float) -> np.ndarray:
    values, vectors = np.linalg.eigh(cov)
    values = np.maximum(values, floor * max(values.max(), 1e-12))
    return (vectors * values**exponent) @ vectors.T


def delays(x: np.ndarray, lag: int, taps: int) -> np.ndarray:
    """(T, F) -> (T, F x (taps + 1)): each frame beside the frames ``lag``, ``2 lag``, ... before it (the first frame
    repeated before the clip starts)."""
    if taps == 0:
        return x
    padded = np.concatenate([np.repeat(x[:1], lag * taps, axis=0), x])
    return np.concatenate([padded[lag * taps - lag * i : len(padded) - lag * i] for i in range(taps + 1)], axis=1)


def coordination_map(
    example: np.ndarray,
    reference: np.ndarray,
    shrink: float,
    floor: float,
    cols: np.ndarray,
    lag: int = 1,
    taps: int = 0,
) -> np.ndarray:
    """A = S_e^(1/2) S_r^(-1/2) over the ``cols`` channels (each frame stacked with ``taps`` frames ``lag`` apart
    before it where ``taps`` > 0): the same for every clip given one example, so a run computes it once per style."""
    ex, ref = (delays(np.asarray(m[:, cols], dtype=np.float64), lag, taps) for m in (example, reference))
    return _power(_covariance(ex, shrink), 0.5, floor) @ _power(_covariance(ref, shrink), -0.5, floor)


def apply_coordination(
    output: np.ndarray, colour: np.ndarray, cols: np.ndarray, lag: int = 1, taps: int = 0
) -> np.ndarray:
    """``output`` (T, F) with its ``cols`` channels' deviations from their means mapped by ``colour``; with taps, a
    frame's output is the current block of the stacked map (a filter over the frames before it)."""
    x = delays(np.asarray(output[:, cols], dtype=np.float64), lag, taps)
    mean = x.mean(0)
    out = output.copy()
    out[:, cols] = (mean + (x - mean) @ colour.T)[:, : len(cols)].astype(np.float32)
    return out


def coordination_transfer(
    output: np.ndarray,
    example: np.ndarray,
    reference: np.ndarray,
    shrink: float,
    floor: float,
    cols: np.ndarray | None = None,
    lag: int = 1,
    taps: int = 0,
    basis: str = "positions",
) -> np.ndarray:
    """``output`` (T, F) with its position channels' deviations from their means mapped by S_e^(1/2) S_r^(-1/2);
    ``cols``: the channels mapped (default every position channel); ``lag``, ``taps``: ``coordination_map``;
    ``basis`` ``bones``: the map over ``bone_channels`` instead, the joints rebuilt from the mapped bones."""
    if basis == "bones":
        ex, ref, out = (bone_channels(m) for m in (example, reference, output))
        every = np.arange(out.shape[1])
        colour = coordination_map(ex, ref, shrink, floor, every, lag, taps)
        return with_bone_channels(output, apply_coordination(out, colour, every, lag, taps))
    cols = position_channels() if cols is None else cols
    colour = coordination_map(example, reference, shrink, floor, cols, lag, taps)
    return apply_coordination(output, colour, cols, lag, taps)


@output_shapers.register("coordination")
class Coordination(OutputShaper):
    """The example's covariance change over its reference on the output's joint positions.

    The positions' deviations x -> A x with A = S_e^(1/2) S_r^(-1/2), S_e and S_r the example's and the reference's
    covariances over their frames, each shrunk toward its diagonal by ``shrink``, eigenvalues floored at ``floor`` x the
    largest. Why: the moment rule is AdaIN's per-channel mean and variance; the whitening and colouring transform (Li et
    al., "Universal style transfer via feature transforms", NeurIPS 2017) is its full-covariance form and carries how a
    style couples the arms, the trunk and the legs, which a clip-standardised judge still sees where posture and
    amplitude are gone. With ``taps`` > 0, x is each frame's positions stacked with those ``lag``, ..., ``taps`` x
    ``lag`` frames before (a delay embedding), so the map also carries the lagged cross-covariances: the phase between
    limbs, alike at zero lag for two limbs moving together or a quarter-cycle apart. That phase has a direction in time,
    so a clip that travels against the example (a backward walk under a forward walk's map, ``travel.opposed``) is
    mapped played backwards, where its limbs lead as the example's do. Taken relative to the reference, the content's
    own coordination (a wave, a kick) is kept and only the style's change to it added: a content as plain as the
    reference comes out with the example's covariance, and the same example and reference change nothing. Only the joint
    positions change; the joint rotations and velocities stay the content's.

    ``basis``: the coordinates x is taken in, ``positions`` (root height and root-relative joints) or ``bones`` (root
    height and each bone's vector, child less parent, the joints rebuilt down the chains after the map). The bones are
    an invertible linear change of the positions' coordinates, but the symmetric square roots are not invariant to
    one, so the two maps differ in the rotation whitening-colouring adds, which is where the style is read; in bone
    coordinates a bone's change moves the joints below it with it, as a skeleton moves. No config names ``bones``: on
    Bandai-2 it reads more with walk examples alone and less with the configs' walk and wave (lab/NOTES.md 0).
    """

    needs_reference = True

    def __init__(
        self, shrink: float = 0.0, floor: float = 1e-3, lag: int = 1, taps: int = 0, basis: str = "positions"
    ) -> None:
        if not (0.0 <= shrink <= 1.0 and 0.0 < floor < 1.0 and lag >= 1 and taps >= 0):
            raise ValueError(
                f"coordination needs shrink in [0, 1], floor in (0, 1), lag >= 1, taps >= 0; got {shrink}, {floor},"
                f" {lag}, {taps}"
            )
        if basis not in BASES:
            raise ValueError(f"coordination basis {basis!r} is not one of {', '.join(BASES)}")
        self.shrink, self.floor, self.lag, self.taps, self.basis = shrink, floor, lag, taps, basis
        self._maps: dict[bytes, np.ndarray] = {}  # by example and reference: a run shapes many clips per example

    def _coordinates(self, motion: np.ndarray) -> np.ndarray:
        """A clip's channels in the map's ``basis``."""
        return bone_channels(motion) if self.basis == "bones" else motion

    def _rebuild(self, output: np.ndarray, mapped: np.ndarray) -> np.ndarray:
        """The output's features from its mapped channels."""
        return with_bone_channels(output, mapped) if self.basis == "bones" else mapped

    def __call__(self, output: np.ndarray, context: ShapeContext) -> np.ndarray:
        if context.reference is None:
            raise ValueError("the coordination shaper needs the example's reference")
        key = hashlib.blake2b(digest_size=16)
        for m in (context.example, context.reference):
            key.update(np.ascontiguousarray(m, dtype=np.float32).tobytes() + str(m.shape).encode())
        x = self._coordinates(output)
        cols = np.arange(x.shape[1]) if self.basis == "bones" else position_channels()
        colour = self._maps.get(key.digest())
        if colour is None:
            if len(self._maps) >= MAPS_KEPT:
                self._maps.pop(next(iter(self._maps)))
            example, reference = (self._coordinates(m) for m in (context.example, context.reference))
            colour = coordination_map(example, reference, self.shrink, self.floor, cols, self.lag, self.taps)
            self._maps[key.digest()] = colour
        if self.taps and opposed(context.content, context.example, context.fps):
            mapped = apply_coordination(x[::-1], colour, cols, self.lag, self.taps)[::-1].copy()
        else:
            mapped = apply_coordination(x, colour, cols, self.lag, self.taps)
        return self._rebuild(output, mapped)


@output_shapers.register("lock_feet")
class LockFeet(OutputShaper):
    """Planted feet held where they were planted (``augment.motion.foot_lock``)."""

    def __call__(self, output: np.ndarray, context: ShapeContext) -> np.ndarray:
        return lock_feet(output)


def toe_contacts(features: np.ndarray) -> np.ndarray:
    """(T, 2) bool: the left and right toe contact channels of raw HumanML3D features."""
    return foot_contacts_from_features(features)[:, [1, 3]]  # (l_ankle, l_toe, r_ankle, r_toe)


def toe_heights(features: np.ndarray) -> np.ndarray:
    """(T, 2): the left and right toe's height above the floor."""
    return np.asarray(features_to_joints(features))[:, [T2M.feet_left[1], T2M.feet_right[1]], 1]


@output_shapers.register("plant_feet")
class PlantFeet(OutputShaper):
    """The content's planted toes held still on the output's legs, and its swing toes' clearance kept
    (``augment.motion.foot_lock.plant_feet``).

    ``clearance``: the share of the content's toe height a swinging toe (not planted in the content) is kept above;
    ``blend``: frames over which a planted toe's shift fades into the swing. Why: a map of the joint positions moves
    the legs while the root path stays the content's, so feet slide when planted and skim the floor when swinging;
    the content keeps its footfalls through a transfer, so its contacts and swing heights say where the feet go.
    """

    def __init__(self, blend: int = 4, clearance: float = 1.0) -> None:
        if blend < 0 or not 0.0 <= clearance <= 1.0:
            raise ValueError(f"plant_feet needs blend >= 0 and clearance in [0, 1], got {blend}, {clearance}")
        self.blend, self.clearance = blend, clearance

    def __call__(self, output: np.ndarray, context: ShapeContext) -> np.ndarray:
        floor = self.clearance * toe_heights(context.content) if self.clearance > 0 else None
        return plant_feet(output, toe_contacts(context.content), blend=self.blend, clearance=floor)


def with_bone_lengths(output: np.ndarray, content: np.ndarray) -> np.ndarray:
    """``output`` (T, F) whose root-relative joints keep each bone's direction at the content's mean bone length."""
    slices = feature_slices(T2M)
    joints = np.stack([root_relative_joints(m) for m in (output, content)])
    out_joints, length = joints[0].copy(), {}
    for chain in T2M.kinematic_chain:
        for parent, child in zip(chain[:-1], chain[1:]):
            length[child] = np.linalg.norm(joints[1, :, child] - joints[1, :, parent], axis=-1).mean()
    for chain in T2M.kinematic_chain:
        for parent, child in zip(chain[:-1], chain[1:]):
            bone = joints[0, :, child] - joints[0, :, parent]
            unit = bone / np.maximum(np.linalg.norm(bone, axis=-1, keepdims=True), 1e-9)
            out_joints[:, child] = out_joints[:, parent] + unit * length[child]
    out = output.copy()
    out[:, slices["ric"]] = out_joints[:, 1:].reshape(len(output), -1).astype(np.float32)
    return out


@output_shapers.register("bone_lengths")
class BoneLengths(OutputShaper):
    """The content's bone lengths on the output's joint positions: a linear map of positions stretches bones, a
    skeleton does not."""

    def __call__(self, output: np.ndarray, context: ShapeContext) -> np.ndarray:
        return with_bone_lengths(output, context.content)


TRUNK = (3, 6, 9, 12, 15)  # spine1, spine2, spine3, neck, head
COLLAR_ARMS = {13: (16, 18, 20), 14: (17, 19, 21)}  # collar -> the arm hanging from it
BELOW_HIPS = (4, 5, 7, 8, 10, 11)  # knees, ankles, feet: they stay where they stand


def highpass(x: np.ndarray, width: int) -> np.ndarray:
    """``x`` (T, ...) less its centred moving average over ``width`` frames (edges padded): its slow drift gone."""
    if width < 2:
        return x
    pad = np.concatenate([np.repeat(x[:1], width // 2, 0), x, np.repeat(x[-1:], width - 1 - width // 2, 0)])
    kernel = np.ones(width) / width
    smooth = np.apply_along_axis(lambda v: np.convolve(v, kernel, mode="valid"), 0, pad)
    return x - smooth


def body_rhythm(motion: np.ndarray, frames: int, width: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(frames,) root height drops below its highest and (frames, 22, 3) root-relative joint deviations from their
    means (trunk and collars only, heights over the root's), the clip's frames looped from its start; ``width`` > 1:
    each high-passed over that many frames first (a take's slow drift would loop as a saw)."""
    sl = feature_slices(T2M)
    root_y = motion[:, sl["root_y"]][:, 0].astype(np.float64)
    joints = np.zeros((len(motion), T2M.n_joints, 3))
    joints[:, 1:] = motion[:, sl["ric"]].reshape(len(motion), T2M.n_joints - 1, 3)
    joints[:, 1:, 1] -= root_y[:, None]  # heights over the root's: the bounce is root_y's alone
    root_y, joints = highpass(root_y, width), highpass(joints, width)
    index = np.arange(frames) % len(motion)
    drop = (root_y - root_y.max())[index]
    sway = np.zeros((frames, T2M.n_joints, 3))
    for j in (*TRUNK, *COLLAR_ARMS):
        sway[:, j] = (joints[:, j] - joints[:, j].mean(0))[index]
    return drop, sway


def beyond_reference(
    drop: np.ndarray, sway: np.ndarray, reference: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """The example's rhythm with each channel scaled by sqrt(1 - its variance in the reference over the example's):
    the body motion the plain reference lacks, none where the style moves the body as plainly."""
    ref_drop, ref_sway = reference
    drop = drop * np.sqrt(np.clip(1.0 - ref_drop.var() / max(drop.var(), 1e-12), 0.0, 1.0))
    sway = sway * np.sqrt(np.clip(1.0 - ref_sway.var(0) / np.maximum(sway.var(0), 1e-12), 0.0, 1.0))
    return drop, sway


def with_body_rhythm(output: np.ndarray, drop: np.ndarray, sway: np.ndarray, gain: float = 1.0) -> np.ndarray:
    """``output`` (T, F) with ``gain`` x a rhythm added: the drop lowers the pelvis and every joint above the knees,
    a trunk or collar joint's sway carries it and, from a collar, the arm hanging from it."""
    sl = feature_slices(T2M)
    out = output.copy()
    ric = out[:, sl["ric"]].reshape(len(out), T2M.n_joints - 1, 3).astype(np.float64)
    for j in (*TRUNK, *COLLAR_ARMS):
        ric[:, j - 1] += gain * sway[:, j]
    for collar, arm in COLLAR_ARMS.items():
        for j in arm:
            ric[:, j - 1] += gain * sway[:, collar]
    above = [j - 1 for j in range(1, T2M.n_joints) if j not in BELOW_HIPS]
    ric[:, above, 1] += gain * drop[:, None]
    out[:, sl["ric"]] = ric.reshape(len(out), -1).astype(np.float32)
    out[:, sl["root_y"]] += (gain * drop[:, None]).astype(np.float32)
    return out


@output_shapers.register("in_place_rhythm")
class InPlaceRhythm(OutputShaper):
    """On a clip that stays in place, shaped by an example that stays in place too (a style's wave for a wave), the
    example's root height drops and trunk and collar sway that its reference lacks, looped onto the output.

    Why: a style's standing actions move the root height and trunk far more than the plain ones, and a plain wave
    barely moves its body, so no map of its joint positions (``coordination``, ``moments``) can give it the style's
    body motion; the example shows it. Each deviation is high-passed over ``highpass_s`` seconds (a take's slow drift
    would loop as a saw) and scaled by ``beyond_reference`` (the part of the example's motion its reference lacks). The
    knees are left to ``plant_feet``, the step after it in the chain, which bends them to feet that stay. A travelling
    clip or example is left alone: a walk's gait rhythm is already the content's own.
    """

    needs_reference = True

    def __init__(self, highpass_s: float = 1.0) -> None:
        if highpass_s < 0:
            raise ValueError(f"in_place_rhythm needs highpass_s >= 0, got {highpass_s}")
        self.highpass_s = highpass_s

    def __call__(self, output: np.ndarray, context: ShapeContext) -> np.ndarray:
        if context.reference is None:
            raise ValueError("the in_place_rhythm shaper needs the example's reference")
        if travels(context.content, context.fps) or travels(context.example, context.fps):
            return output
        width = round(self.highpass_s * context.fps)
        drop, sway = body_rhythm(np.asarray(context.example), len(output), width)
        reference = body_rhythm(np.asarray(context.reference), len(output), width)
        return with_body_rhythm(output, *beyond_reference(drop, sway, reference))


def flight(features: np.ndarray) -> float:
    """The share of frames with no foot on the ground: a run's flight phases (0 for a walk or a wave)."""
    return float((~foot_contacts_from_features(features).any(-1)).mean())


def example_tempo(context: ShapeContext) -> float:
    """The example's cycle rate over its reference's (``tempo.style_tempo``): 1.0 when either does not repeat, when
    the content does not move as the example does (travelling or in place), or when the two are different gaits
    (``flight`` more than ``FLIGHT_APART`` apart: a walk's cadence over a run's is not a style's tempo)."""
    if context.reference is None:
        raise ValueError("the match_tempo shaper needs the example's reference")
    if travels(context.content, context.fps) != travels(context.example, context.fps):
        return 1.0
    if abs(flight(context.example) - flight(context.reference)) > FLIGHT_APART:
        return 1.0
    tempo, _ = style_tempo([(context.example, context.fps)], [(context.reference, context.fps)], min_references=1)
    return 1.0 if tempo is None else tempo


@output_shapers.register("match_tempo")
class MatchTempo(OutputShaper):
    """The output played at the example's cycle rate over its reference's, and the steps after it on that clock.

    Why: ``coordination``'s lagged covariances and ``moments``' variances compare the example with its reference, and
    where the two walk at different cadences (a slow style against the nearest plain walk) the cadence comes through
    as a change of coordination: applied at the content's own cadence, it lengthens strides and turns walks into runs
    and turns. Played at the example's rate, with the reference and the content retimed to it for the steps after
    (``context_after``), the map holds only what the style changes at one cadence, and the output keeps the style's
    pace. A retimed clip has at most ``cap`` frames, or its own count if longer (HumanML3D's 196); a slower one loses
    its end. The run retimes the captions' segments with it (``shaping.ShapedModel``).
    """

    needs_reference = True

    def __init__(self, cap: int = 196) -> None:
        if cap < 2:
            raise ValueError(f"match_tempo needs cap >= 2, got {cap}")
        self.cap = cap
        self._measured: tuple[ShapeContext, float] | None = None  # the tempo ``__call__`` found, for ``context_after``

    def _tempo(self, context: ShapeContext) -> float:
        if self._measured is None or self._measured[0] is not context:
            self._measured = (context, example_tempo(context))
        return self._measured[1]

    def __call__(self, output: np.ndarray, context: ShapeContext) -> np.ndarray:
        return retime(output, self._tempo(context), max(len(output), self.cap))

    def context_after(self, context: ShapeContext) -> ShapeContext:
        tempo = self._tempo(context)
        if tempo == 1.0 or context.reference is None:
            return context
        content = retime(context.content, tempo, max(len(context.content), self.cap))
        reference = retime(context.reference, tempo, max(len(context.reference), self.cap))
        return ShapeContext(content, context.example, reference, context.fps, context.alike)
