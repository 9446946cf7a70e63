"""Tempo: how fast a motion cycles, how a style changes it, and retiming a clip to a new tempo.

Styles change timing as much as posture: a depressed or old walk cycles slower than a neutral one, a childlike one
faster. A diffusion transfer that keeps the content's trajectory (Hu et al., sec. 7.1) keeps the content's clock too,
so this module measures the style's tempo from its examples and retimes the content before the transfer adds the
posture. Tempo = (cycle period of comparable neutral motions) / (cycle period of the style's examples), below 1
slower; a period is the lag of the strongest repeat in the autocorrelation of the root-relative joint positions, the
standard way to find the pitch of a periodic signal.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from motionaug.augment.motion.features import feature_slices
from motionaug.augment.motion.rotations import qinv_np, qrot_np
from motionaug.schemas.captions import Caption
from motionaug.schemas.skeleton import T2M, Skeleton

MIN_PERIOD_S = 0.4  # faster than any gait cycle or gesture repeat
MAX_PERIOD_S = 3.0
MAX_LAG_SHARE = 0.6  # a repeat must overlap itself over at least 40% of the clip
PEAK_SHARE = 0.8  # among strong peaks take the shortest lag: a 2-cycle repeat is not the period
MIN_STRENGTH = 0.3  # autocorrelation a repeat needs to count as periodic
TEMPO_RANGE = (0.25, 4.0)


def _autocorrelation(x: np.ndarray, max_lag: int) -> np.ndarray:
    """Normalised autocorrelation (lag 0 = 1) of a (T, C) signal summed over channels, unbiased per lag."""
    x = x - x.mean(axis=0)
    n = len(x)
    ac = np.array([float((x[: n - lag] * x[lag:]).sum()) / (n - lag) for lag in range(max_lag + 1)])
    return ac / ac[0] if ac[0] > 0 else np.zeros_like(ac)


def cycle_period(features: np.ndarray, fps: float, skeleton: Skeleton = T2M) -> float | None:
    """Seconds of one motion cycle (a gait cycle: two steps), or None when the motion does not repeat.

    Uses the root-relative joint positions (``ric``), which do not drift with the path, so a walk in a curve
    repeats as cleanly as a straight one.
    """
    x = np.asarray(features, dtype=np.float64)[:, feature_slices(skeleton)["ric"]]
    lo = max(1, int(MIN_PERIOD_S * fps))  # >= 1: the peak search reads one lag below it
    hi = min(int(MAX_PERIOD_S * fps), int(MAX_LAG_SHARE * len(x)))
    if hi <= lo + 2:
        return None
    ac = _autocorrelation(x, hi + 1)
    seg = ac[lo - 1 : hi + 2]  # one extra lag each side so peaks at the ends are seen
    peaks = [
        i for i in range(1, len(seg) - 1) if seg[i] >= seg[i - 1] and seg[i] >= seg[i + 1] and seg[i] >= MIN_STRENGTH
    ]
    if not peaks:
        return None
    top = max(seg[i] for i in peaks)
    i = next(i for i in peaks if seg[i] >= PEAK_SHARE * top)
    y0, y1, y2 = seg[i - 1], seg[i], seg[i + 1]
    curvature = y0 - 2.0 * y1 + y2
    offset = 0.5 * (y0 - y2) / curvature if curvature < 0 else 0.0  # parabolic refinement of the peak
    return float((lo - 1 + i + offset) / fps)


def median_period(motions: Sequence[tuple[np.ndarray, float]]) -> tuple[float | None, int]:
    """Median cycle period of the (features, fps) motions that repeat, and how many did."""
    periods = [p for p in (cycle_period(m, fps) for m, fps in motions) if p is not None]
    return (float(np.median(periods)) if periods else None), len(periods)


def style_tempo(
    examples: Sequence[tuple[np.ndarray, float]],
    references: Sequence[tuple[np.ndarray, float]],
    min_references: int = 3,
) -> tuple[float | None, str]:
    """(tempo, why): the style's speed-up of the cycle over neutral references of the same kind of motion.

    Motions are (features, fps). None when the examples do not repeat or too few references do (the caller
    keeps the content's clock).
    """
    example, n_example = median_period(examples)
    reference, n_reference = median_period(references)
    if example is None:
        return None, "the style examples do not repeat (no cycle to measure)"
    if reference is None or n_reference < min_references:
        return None, f"{n_reference} of {len(references)} neutral references repeat (need {min_references})"
    tempo = float(np.clip(reference / example, *TEMPO_RANGE))
    why = (
        f"example cycle {example:.2f} s ({n_example} of {len(examples)} examples), neutral {reference:.2f} s "
        f"({n_reference} of {len(references)} references)"
    )
    return tempo, why


def retimed_length(n_frames: int, tempo: float, max_frames: int) -> int:
    """Frames of a clip played at ``tempo`` times its speed, capped at ``max_frames`` (the end is cut)."""
    return int(min(max(2, round(n_frames / tempo)), max_frames))


def _at(values: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Rows of ``values`` linearly interpolated at fractional frame times ``t`` (within 0 .. len - 1)."""
    i0 = np.floor(t).astype(np.int64)
    i1 = np.minimum(i0 + 1, len(values) - 1)
    w = (t - i0)[:, None]
    return (1.0 - w) * values[i0] + w * values[i1]


def _yaw(angle: np.ndarray) -> np.ndarray:
    """The root-yaw quaternions of HumanML3D's ``recover_root_rot_pos`` for accumulated angles."""
    zero = np.zeros_like(angle)
    return np.stack([np.cos(angle), zero, np.sin(angle), zero], axis=-1)


def _retimed_root(f: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(root angular velocity, root linear velocity in the root frame) of the retimed clip.

    The heading and the world path are accumulated as the dataset's recovery does, sampled at the new frames'
    edges, and turned back into per-frame rates in each new frame's own heading, so the recovered path passes
    exactly the same places.
    """
    heading = np.concatenate([[0.0], np.cumsum(f[:, 0])])  # heading of frames 0..n
    local = np.stack([f[:, 1], np.zeros(len(f)), f[:, 2]], axis=-1)
    world = qrot_np(qinv_np(_yaw(heading[1:])), local)  # the step into frame i + 1 turns with that frame's heading
    path = np.concatenate([np.zeros((1, 3)), np.cumsum(world, axis=0)])
    heading_new, path_new = _at(heading[:, None], edges)[:, 0], _at(path, edges)
    steps = qrot_np(_yaw(heading_new[1:]), np.diff(path_new, axis=0))
    return np.diff(heading_new)[:, None], steps[:, [0, 2]]


def retime(features: np.ndarray, tempo: float, max_frames: int, skeleton: Skeleton = T2M) -> np.ndarray:
    """The clip played at ``tempo`` times its speed (below 1: slower, more frames), in HumanML3D features.

    Poses (positions, rotations, root height) are interpolated linearly in time. Rates are resampled over each
    new frame's time span: the root's through its accumulated heading and world path (so the recovered path
    passes the same places at the new pace), the joint velocities through their running sums. Interpolating
    the rates themselves would smear the first frame's heading step (HumanML3D resets the frame-0 root
    rotation) and bend a curved path. Foot contacts are interpolated and thresholded at 0.5. A slower clip
    longer than ``max_frames`` loses its end.
    """
    if not tempo > 0:
        raise ValueError(f"tempo must be > 0, got {tempo}")
    f = np.asarray(features, dtype=np.float64)
    if tempo == 1.0:
        return f.astype(np.float32)
    n, n_out = len(f), retimed_length(len(f), tempo, max_frames)
    out = _at(f, np.minimum(np.arange(n_out) * tempo, n - 1))
    edges = np.minimum(np.arange(n_out + 1) * tempo, n)  # new frame m spans old time [m * tempo, (m + 1) * tempo]
    slices = feature_slices(skeleton)
    out[:, slices["root_rot_vel"]], out[:, slices["root_lin_vel"]] = _retimed_root(f, edges)
    rate = f[:, slices["local_vel"]]
    running = np.concatenate([np.zeros((1, rate.shape[1])), np.cumsum(rate, axis=0)])
    out[:, slices["local_vel"]] = np.diff(_at(running, edges), axis=0)
    feet = slices["feet"]
    out[:, feet] = out[:, feet] >= 0.5
    return out.astype(np.float32)


def ground_speed(features: np.ndarray, skeleton: Skeleton = T2M) -> float:
    """The root's mean ground speed, metres per frame (the length of ``root_lin_vel`` averaged over frames)."""
    steps = np.asarray(features, dtype=np.float64)[:, feature_slices(skeleton)["root_lin_vel"]]
    return float(np.linalg.norm(steps, axis=1).mean())


def paced(features: np.ndarray, ratio: float, skeleton: Skeleton = T2M) -> np.ndarray:
    """The clip with its root carried ``ratio`` times as far each frame, on the same heading: the path keeps its
    turns, the body its poses and clock, only the ground speed changes. Every joint's velocity (``local_vel``)
    gains the root's extra ground step, so the features stay consistent (exactly on a straight path; on a curve
    up to the one-frame heading offset between HumanML3D's two velocity blocks)."""
    if not ratio > 0:
        raise ValueError(f"ratio must be > 0, got {ratio}")
    f = np.array(features, dtype=np.float64)
    slices = feature_slices(skeleton)
    step = f[:, slices["root_lin_vel"]]
    extra = (ratio - 1.0) * step
    joints_vel = f[:, slices["local_vel"]].reshape(len(f), skeleton.n_joints, 3)
    joints_vel[:, :, 0] += extra[:, None, 0]
    joints_vel[:, :, 2] += extra[:, None, 1]
    f[:, slices["local_vel"]] = joints_vel.reshape(len(f), -1)
    f[:, slices["root_lin_vel"]] = ratio * step
    return f.astype(np.float32)


def retime_captions(captions: Sequence[Caption], tempo: float, duration_s: float) -> list[Caption]:
    """Captions of a clip played at ``tempo``: a segment's start and end move with the new clock.

    Whole-clip captions (0.0#0.0) stay as they are; a segment is clamped to the retimed clip's ``duration_s``
    (a slowed clip may lose its end) and dropped only when nothing of it is left.
    """
    if tempo == 1.0:
        return list(captions)
    out = []
    for caption in captions:
        if caption.whole_clip:
            out.append(caption)
            continue
        start, end = min(caption.start / tempo, duration_s), min(caption.end / tempo, duration_s)
        if end > start:
            out.append(caption.model_copy(update={"start": round(start, 3), "end": round(end, 3)}))
    return out
