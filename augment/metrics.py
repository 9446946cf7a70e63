"""Evaluation metrics as pure functions over numpy arrays or torch tensors.

CRA/SRA (recognition accuracy), FMD (Frechet distance of classifier features), MPJPE, foot skating,
foot-contact agreement, diversity, T2M-style retrieval R@k, and the Wilson interval every table's
shares carry. Joint positions are in metres, Y up,
floor at y = 0 (HumanML3D's extraction puts the lowest foot of a clip on the floor).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

import numpy as np
import torch
from scipy import linalg

from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import Skeleton

ArrayLike = np.ndarray | torch.Tensor

# HumanML3D foot contact rule (motion_representation / process_file): a foot joint is in contact when its
# squared per-frame displacement, summed over x, y, z, is below 0.002 (metres^2, 20 fps).
HUMANML3D_CONTACT_VEL_THRESH = 0.002


def _np(x: ArrayLike, name: str) -> np.ndarray:
    """numpy float64 (or bool/int kept) view of an array or tensor."""
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu().numpy()
    arr = np.asarray(x)
    if arr.dtype.kind == "f":
        arr = arr.astype(np.float64)
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        raise MotionDataError(name, "contains NaN or inf")
    return arr


def recognition_accuracy(logits_or_preds: ArrayLike, labels: ArrayLike) -> float:
    """Share of correct predictions (CRA with the content classifier, SRA with the style classifier).

    Accepts logits ``(N, C)`` (argmax taken) or predicted class ids ``(N,)``.
    """
    scores = _np(logits_or_preds, "predictions")
    truth = _np(labels, "labels").astype(np.int64)
    preds = scores.argmax(axis=-1) if scores.ndim == truth.ndim + 1 else scores.astype(np.int64)
    if preds.shape != truth.shape:
        raise MotionDataError("predictions", f"shape {preds.shape} does not match labels {truth.shape}")
    if truth.size == 0:
        raise MotionDataError("labels", "empty; accuracy is undefined")
    return float((preds == truth).mean())


def _mean_cov(feats: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
    if feats.ndim != 2 or feats.shape[0] < 2:
        raise MotionDataError(name, f"needs features (N >= 2, F), got shape {feats.shape}")
    return feats.mean(axis=0), np.atleast_2d(np.cov(feats, rowvar=False))


def frechet_distance(feats_a: ArrayLike, feats_b: ArrayLike, eps: float = 1e-6) -> float:
    """Frechet distance between Gaussians fitted to two feature sets (FID formula; FMD on motion features).

    ``|mu_a - mu_b|^2 + tr(S_a + S_b - 2 sqrt(S_a S_b))``. When the product is singular, ``eps * I`` is
    added to both covariances; the tiny imaginary part sqrtm leaves on near-singular input is dropped.
    """
    a, b = _np(feats_a, "features a"), _np(feats_b, "features b")
    mu_a, cov_a = _mean_cov(a, "features a")
    mu_b, cov_b = _mean_cov(b, "features b")
    if mu_a.shape != mu_b.shape:
        raise MotionDataError("features", f"widths differ: {mu_a.shape[0]} vs {mu_b.shape[0]}")
    covmean = linalg.sqrtm(cov_a @ cov_b)
    if not np.isfinite(covmean).all():
        offset = np.eye(cov_a.shape[0]) * eps
        covmean = linalg.sqrtm((cov_a + offset) @ (cov_b + offset))
    if np.iscomplexobj(covmean):
        scale = max(1.0, float(np.abs(covmean.real).max()))
        if np.abs(covmean.imag).max() > 1e-3 * scale:
            raise MotionDataError("frechet distance", "sqrt of the covariance product has a large imaginary part")
        covmean = covmean.real
    diff = mu_a - mu_b
    value = diff @ diff + np.trace(cov_a) + np.trace(cov_b) - 2.0 * np.trace(covmean)
    return float(max(value, 0.0))


def _frame_mask(mask: ArrayLike | None, shape: tuple[int, ...]) -> np.ndarray:
    """Boolean ``shape`` mask (all True when None)."""
    if mask is None:
        return np.ones(shape, dtype=bool)
    m = _np(mask, "mask").astype(bool)
    if m.shape != shape:
        raise MotionDataError("mask", f"shape {m.shape} does not match frames {shape}")
    return m


def mpjpe(pred_joints: ArrayLike, gt_joints: ArrayLike, mask: ArrayLike | None = None) -> float:
    """Mean per-joint position error over valid frames, in the joints' units. ``(..., T, J, 3)``; mask ``(..., T)``."""
    pred, gt = _np(pred_joints, "predicted joints"), _np(gt_joints, "reference joints")
    if pred.shape != gt.shape or pred.ndim < 3 or pred.shape[-1] != 3:
        raise MotionDataError("joints", f"need matching (..., T, J, 3) arrays, got {pred.shape} and {gt.shape}")
    valid = _frame_mask(mask, pred.shape[:-2])
    if not valid.any():
        raise MotionDataError("mask", "no valid frame")
    errors = np.linalg.norm(pred - gt, axis=-1)  # (..., T, J)
    return float(errors[valid].mean())


def _check_joints(joints: np.ndarray, skeleton: Skeleton) -> None:
    if joints.ndim < 3 or joints.shape[-2:] != (skeleton.n_joints, 3):
        raise MotionDataError(
            "joints", f"need (..., T, {skeleton.n_joints}, 3) for skeleton {skeleton.name}, got {joints.shape}"
        )


def foot_skating_ratio(
    joints: ArrayLike,
    skeleton: Skeleton,
    fps: float,
    height_thresh: float = 0.05,
    vel_thresh: float = 0.5,
    mask: ArrayLike | None = None,
) -> float:
    """Share of frame transitions in which a foot touching the ground slides.

    Thresholds follow GMD (Karunratanakul et al., 2023): a foot (its toe joint, the lowest point;
    ``skeleton.feet_*[1]``) touches the ground when its height is below ``height_thresh`` (5 cm) in both
    frames of a transition, and slides when its ground-plane speed exceeds ``vel_thresh`` (0.5 m/s,
    i.e. 2.5 cm per frame at 20 fps). A transition counts once if either foot skates.
    ``joints (..., T, J, 3)``; ``mask (..., T)`` marks real frames (a transition needs both frames real).
    """
    pos = _np(joints, "joints")
    _check_joints(pos, skeleton)
    if pos.shape[-3] < 2:
        raise MotionDataError("joints", "need at least 2 frames to measure sliding")
    valid = _frame_mask(mask, pos.shape[:-2])
    toes = pos[..., [skeleton.feet_left[1], skeleton.feet_right[1]], :]  # (..., T, 2, 3)
    low = toes[..., 1] < height_thresh  # (..., T, 2)
    grounded = low[..., 1:, :] & low[..., :-1, :]  # (..., T-1, 2)
    step = toes[..., 1:, :, :] - toes[..., :-1, :, :]
    speed = np.linalg.norm(step[..., [0, 2]], axis=-1) * fps  # (..., T-1, 2)
    skating = (grounded & (speed > vel_thresh)).any(axis=-1)  # (..., T-1)
    pair_valid = valid[..., 1:] & valid[..., :-1]
    if not pair_valid.any():
        raise MotionDataError("mask", "no pair of consecutive valid frames")
    return float(skating[pair_valid].mean())


def foot_contacts_from_joints(
    joints: ArrayLike, skeleton: Skeleton, vel_thresh: float = HUMANML3D_CONTACT_VEL_THRESH
) -> np.ndarray:
    """HumanML3D contact labels ``(..., T-1, 4)`` bool, ordered (l_ankle, l_toe, r_ankle, r_toe) as in the features.

    Contact when the squared per-frame displacement (sum over x, y, z) is below ``vel_thresh``.
    """
    pos = _np(joints, "joints")
    _check_joints(pos, skeleton)
    feet = pos[..., [*skeleton.feet_left, *skeleton.feet_right], :]  # (..., T, 4, 3)
    sq_disp = ((feet[..., 1:, :, :] - feet[..., :-1, :, :]) ** 2).sum(axis=-1)
    return sq_disp < vel_thresh


def foot_contacts_from_features(features: ArrayLike, threshold: float = 0.5) -> np.ndarray:
    """Contact labels ``(..., T, 4)`` from the last 4 channels of *unnormalised* HumanML3D features."""
    feats = _np(features, "features")
    if feats.shape[-1] < 4:
        raise MotionDataError("features", f"need the 4 trailing contact channels, got width {feats.shape[-1]}")
    return feats[..., -4:] > threshold


def foot_contact_accuracy(pred_contacts: ArrayLike, ref_contacts: ArrayLike, mask: ArrayLike | None = None) -> float:
    """Share of (frame, foot joint) contact labels that agree; ``(..., T, 4)``, mask ``(..., T)``."""
    pred = _np(pred_contacts, "predicted contacts").astype(bool)
    ref = _np(ref_contacts, "reference contacts").astype(bool)
    if pred.shape != ref.shape or pred.ndim < 2:
        raise MotionDataError("contacts", f"need matching (..., T, feet) arrays, got {pred.shape} and {ref.shape}")
    valid = _frame_mask(mask, pred.shape[:-1])
    if not valid.any():
        raise MotionDataError("mask", "no valid frame")
    return float((pred == ref)[valid].mean())


def diversity(feats: ArrayLike, n_pairs: int = 300, seed: int = 0) -> float:
    """Mean Euclidean distance between two random index sets of ``n_pairs`` samples (T2M's Diversity)."""
    x = _np(feats, "features")
    if x.ndim != 2:
        raise MotionDataError("features", f"need (N, F), got shape {x.shape}")
    if x.shape[0] < n_pairs:
        raise MotionDataError(
            "features", f"{x.shape[0]} samples; diversity with {n_pairs} pairs needs at least that many"
        )
    rng = np.random.default_rng(seed)
    first = rng.choice(x.shape[0], n_pairs, replace=False)
    second = rng.choice(x.shape[0], n_pairs, replace=False)
    return float(np.linalg.norm(x[first] - x[second], axis=-1).mean())


def _distance_matrix(queries: np.ndarray, candidates: np.ndarray, metric: str) -> np.ndarray:
    if metric == "euclidean":
        return np.linalg.norm(queries[:, None, :] - candidates[None, :, :], axis=-1)
    q = queries / np.maximum(np.linalg.norm(queries, axis=-1, keepdims=True), 1e-12)
    c = candidates / np.maximum(np.linalg.norm(candidates, axis=-1, keepdims=True), 1e-12)
    return 1.0 - q @ c.T


def retrieval_r_at_k(
    motion_emb: ArrayLike,
    text_emb: ArrayLike,
    k: int = 1,
    pool: int = 32,
    metric: Literal["cosine", "euclidean"] = "cosine",
    seed: int | None = None,
) -> float:
    """R-precision at ``k``: share of captions whose own motion ranks in the top ``k`` of its pool.

    As in T2M evaluation, pairs ``(motion_emb[i], text_emb[i])`` are split into consecutive pools of
    ``pool`` (a trailing partial pool is dropped), optionally after a seeded shuffle; each caption ranks
    the pool's motions. T2M uses Euclidean distance; cosine is the default here because the motion
    encoder is trained with a cosine loss.
    """
    m, t = _np(motion_emb, "motion embeddings"), _np(text_emb, "text embeddings")
    if m.ndim != 2 or m.shape != t.shape:
        raise MotionDataError("embeddings", f"need matching (N, F) arrays, got {m.shape} and {t.shape}")
    if metric not in ("cosine", "euclidean"):
        raise MotionDataError("retrieval", f"unknown metric {metric!r}")
    if not 1 <= k <= pool:
        raise MotionDataError("retrieval", f"k={k} must be in 1..pool={pool}")
    if m.shape[0] < pool:
        raise MotionDataError("embeddings", f"{m.shape[0]} pairs; retrieval needs at least one pool of {pool}")
    order = np.random.default_rng(seed).permutation(m.shape[0]) if seed is not None else np.arange(m.shape[0])
    hits = []
    for start in range(0, m.shape[0] - pool + 1, pool):
        idx = order[start : start + pool]
        dist = _distance_matrix(t[idx], m[idx], metric)  # (pool, pool): caption x motion
        own = np.diag(dist)[:, None]
        rank = (dist < own).sum(axis=1)  # motions strictly closer than the caption's own
        hits.append(rank < k)
    return float(np.concatenate(hits).mean())


def wilson_interval(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95% Wilson score interval of a proportion; it stays inside [0, 1] at 0% and 100%, unlike the normal one."""
    if n == 0:
        return (math.nan, math.nan)
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return (max(0.0, centre - half), min(1.0, centre + half))


def matched_fmd(feats_a: np.ndarray, feats_b: np.ndarray, seed: int) -> tuple[float, int]:
    """FMD with both sets drawn without replacement to the smaller count, which it returns too.

    FMD is biased by the sample count, so two rows are comparable only at the same count.
    """
    n = min(len(feats_a), len(feats_b))
    rng = np.random.default_rng(seed)
    a = np.asarray(feats_a)[rng.choice(len(feats_a), n, replace=False)]
    b = np.asarray(feats_b)[rng.choice(len(feats_b), n, replace=False)]
    return frechet_distance(a, b), n


def mean_foot_skating(joints: Sequence[np.ndarray], skeleton: Skeleton, fps: float) -> float:
    """``foot_skating_ratio`` averaged over clips of at least two frames."""
    return float(np.mean([foot_skating_ratio(j, skeleton, fps) for j in joints if len(j) >= 2]))
