"""Metric functions against hand-computed values, plus the HumanML3D contact rule on real data."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from motionaug.augment.metrics import (
    diversity,
    foot_contact_accuracy,
    foot_contacts_from_features,
    foot_contacts_from_joints,
    foot_skating_ratio,
    frechet_distance,
    matched_fmd,
    mean_foot_skating,
    mpjpe,
    recognition_accuracy,
    retrieval_r_at_k,
    wilson_interval,
)
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import T2M


def test_recognition_accuracy_from_logits_and_ids() -> None:
    logits = torch.tensor([[2.0, 0.1], [0.0, 1.0], [3.0, -1.0], [0.2, 0.1]])
    labels = torch.tensor([0, 1, 1, 0])
    assert recognition_accuracy(logits, labels) == 0.75
    assert recognition_accuracy(np.array([0, 1, 1, 1]), np.array([0, 1, 1, 0])) == 0.75
    with pytest.raises(MotionDataError, match="does not match labels"):
        recognition_accuracy(np.array([0, 1]), np.array([0, 1, 1]))


def test_frechet_distance_hand_values() -> None:
    rng = np.random.default_rng(0)
    a = rng.normal(size=(500, 4))
    assert frechet_distance(a, a) == pytest.approx(0.0, abs=1e-6)
    shift = np.array([1.0, -2.0, 0.5, 0.0])
    # same covariance exactly, so the distance is |shift|^2 = 5.25
    assert frechet_distance(a, a + shift) == pytest.approx(5.25, rel=1e-6)
    # 1-D: (mu_a - mu_b)^2 + (sigma_a - sigma_b)^2
    x = np.array([[0.0], [2.0]])  # mean 1, sample variance 2
    y = np.array([[3.0], [11.0]])  # mean 7, sample variance 32
    assert frechet_distance(x, y) == pytest.approx(36.0 + (math.sqrt(2) - math.sqrt(32)) ** 2, rel=1e-9)


def test_frechet_distance_is_robust_to_singular_covariances() -> None:
    rng = np.random.default_rng(1)
    a = rng.normal(size=(5, 16))  # fewer samples than dimensions: singular covariance
    b = rng.normal(size=(6, 16))
    value = frechet_distance(torch.from_numpy(a), torch.from_numpy(b))
    assert math.isfinite(value) and value > 0
    with pytest.raises(MotionDataError, match="N >= 2"):
        frechet_distance(a[:1], b)
    with pytest.raises(MotionDataError, match="widths differ"):
        frechet_distance(a, b[:, :8])


def test_mpjpe_hand_values() -> None:
    gt = np.zeros((2, 4, 22, 3))
    pred = gt.copy()
    pred[..., 0] += 3.0
    pred[..., 1] += 4.0
    assert mpjpe(pred, gt) == pytest.approx(5.0)
    pred[1, 2:] += 100.0  # padding: excluded by the mask
    mask = np.ones((2, 4), dtype=bool)
    mask[1, 2:] = False
    assert mpjpe(pred, gt, mask) == pytest.approx(5.0)
    with pytest.raises(MotionDataError, match="matching"):
        mpjpe(pred[:, :3], gt)


def feet_on_floor(frames: int) -> np.ndarray:
    """A standing T2M pose: every joint 1 m up except the feet, which rest on the floor."""
    joints = np.zeros((frames, 22, 3))
    joints[..., 1] = 1.0
    for joint in (*T2M.feet_left, *T2M.feet_right):
        joints[:, joint, 1] = 0.02
    return joints


def test_foot_skating_planted_vs_sliding() -> None:
    planted = feet_on_floor(10)
    assert foot_skating_ratio(planted, T2M, fps=20) == 0.0
    sliding = planted.copy()
    sliding[:, T2M.feet_left[1], 0] = np.arange(10) * 0.05  # 1 m/s along x while on the floor
    assert foot_skating_ratio(sliding, T2M, fps=20) == 1.0
    assert foot_skating_ratio(sliding, T2M, fps=20, vel_thresh=1.5) == 0.0
    lifted = sliding.copy()
    lifted[:, T2M.feet_left[1], 1] = 0.3  # a swinging foot in the air is not skating
    assert foot_skating_ratio(lifted, T2M, fps=20) == 0.0
    half = planted.copy()
    half[5:, T2M.feet_right[1], 2] = np.arange(5) * 0.05  # slides over 4 of the 9 transitions
    assert foot_skating_ratio(half, T2M, fps=20) == pytest.approx(4 / 9)
    batch = np.stack([planted, sliding])
    mask = np.ones((2, 10), dtype=bool)
    mask[1, 4:] = False  # 9 planted + 3 sliding transitions
    assert foot_skating_ratio(batch, T2M, fps=20, mask=mask) == pytest.approx(3 / 12)


def test_foot_contacts_rule_and_accuracy() -> None:
    joints = feet_on_floor(6)
    joints[:, T2M.feet_right[0], 2] = np.arange(6) * 0.05  # right ankle: 0.0025 m^2 per frame > 0.002
    contacts = foot_contacts_from_joints(joints, T2M)
    assert contacts.shape == (5, 4)
    assert contacts[:, [0, 1, 3]].all() and not contacts[:, 2].any()
    ref = np.ones((5, 4), dtype=bool)
    assert foot_contact_accuracy(contacts, ref) == pytest.approx(15 / 20)
    assert foot_contact_accuracy(contacts, ref, mask=np.array([1, 1, 0, 0, 0], dtype=bool)) == pytest.approx(6 / 8)
    feats = np.zeros((3, 263))
    feats[:, -4:] = [1.0, 0.0, 1.0, 0.0]
    assert foot_contacts_from_features(feats).tolist() == [[True, False, True, False]] * 3


def test_contact_rule_reproduces_the_dataset_channels(shared_data: Path) -> None:
    joints = np.load(shared_data / "humanml3d_sample" / "new_joints" / "012314.npy")  # (170, 22, 3)
    feats = np.load(shared_data / "humanml3d_sample" / "new_joint_vecs" / "012314.npy")  # (170, 263)
    from_joints = foot_contacts_from_joints(joints, T2M)  # (169, 4): frame t from t -> t+1
    from_feats = foot_contacts_from_features(feats[:-1])
    assert foot_contact_accuracy(from_joints, from_feats) > 0.99


def test_diversity() -> None:
    rng = np.random.default_rng(0)
    same = np.tile(rng.normal(size=(1, 8)), (50, 1))
    assert diversity(same, n_pairs=20) == 0.0
    x = rng.normal(size=(2000, 64))
    # E|x - y| for x, y ~ N(0, I_64) is close to sqrt(2 * 64)
    assert diversity(x, n_pairs=300, seed=3) == pytest.approx(math.sqrt(128), rel=0.05)
    assert diversity(2 * x, n_pairs=300, seed=3) == pytest.approx(2 * diversity(x, n_pairs=300, seed=3))
    with pytest.raises(MotionDataError, match="needs at least"):
        diversity(x[:10], n_pairs=300)


def test_retrieval_r_at_k() -> None:
    rng = np.random.default_rng(0)
    emb = rng.normal(size=(70, 16))
    assert retrieval_r_at_k(emb, emb, k=1) == 1.0  # 2 pools of 32; the last 6 pairs are dropped
    assert retrieval_r_at_k(emb, emb, k=1, metric="euclidean", seed=5) == 1.0
    unrelated = rng.normal(size=(64, 16))
    assert retrieval_r_at_k(emb[:64], unrelated, k=32) == 1.0
    # pool of 2 by hand: caption 0 is nearer motion 1, caption 1 is nearer motion 1
    motions = np.array([[1.0, 0.0], [0.0, 1.0]])
    texts = np.array([[0.1, 1.0], [0.0, 1.0]])
    assert retrieval_r_at_k(motions, texts, k=1, pool=2) == 0.5
    assert retrieval_r_at_k(motions, texts, k=2, pool=2) == 1.0
    with pytest.raises(MotionDataError, match="at least one pool"):
        retrieval_r_at_k(emb[:10], emb[:10])


def test_features_to_joints_matches_the_dataset_and_feeds_the_classifier(shared_data: Path) -> None:
    from motionaug.augment.motion.batch import pad_batch
    from motionaug.augment.motion.features import features_to_joints
    from motionaug.models.evaluators import content_classifier

    feats = np.load(shared_data / "humanml3d_sample" / "new_joint_vecs" / "012314.npy")
    joints_ref = np.load(shared_data / "humanml3d_sample" / "new_joints" / "012314.npy")
    mean = np.load(shared_data / "humanml3d_sample" / "Mean.npy")
    std = np.load(shared_data / "humanml3d_sample" / "Std.npy")
    joints = features_to_joints((feats - mean) / std, T2M, mean=mean, std=std)
    np.testing.assert_allclose(joints, joints_ref, atol=1e-4)
    batch, mask = pad_batch([joints, joints[:50]])
    assert batch.shape == (2, 170, 22, 3) and mask.sum(dim=1).tolist() == [170, 50]
    model = content_classifier(4, size="tiny").eval()
    assert model(batch, mask).shape == (2, 4)
    with pytest.raises(MotionDataError, match="width 262"):
        features_to_joints(feats[:, :262], T2M)


def test_wilson_interval_stays_inside_0_1_and_narrows_with_n() -> None:
    low, high = wilson_interval(0, 10)
    assert low == 0.0 and 0.2 < high < 0.35
    low, high = wilson_interval(10, 10)
    assert high == 1.0 and 0.65 < low < 0.8
    low, high = wilson_interval(5, 10)
    assert abs((low + high) / 2 - 0.5) < 1e-12
    assert wilson_interval(50, 100)[1] - wilson_interval(50, 100)[0] < high - low
    assert all(np.isnan(wilson_interval(0, 0)))


def test_matched_fmd_draws_both_sets_to_the_smaller_count() -> None:
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(40, 4)), rng.normal(size=(90, 4)) + 3.0
    fmd, n = matched_fmd(a, b, seed=1)
    assert n == 40 and fmd == matched_fmd(a, b, seed=1)[0]
    assert fmd > matched_fmd(a, rng.normal(size=(90, 4)), seed=1)[0] + 10


def test_mean_foot_skating_skips_one_frame_clips() -> None:
    still = np.zeros((10, T2M.n_joints, 3))
    assert mean_foot_skating([still, still[:1]], T2M, 20.0) == foot_skating_ratio(still, T2M, 20.0)
