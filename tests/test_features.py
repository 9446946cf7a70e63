"""Kinematics and HumanML3D features against the real dataset clip and synthetic motion."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from motionaug.augment.motion.features import (
    FEATURE_BLOCKS,
    Normalizer,
    compute_mean_std,
    extract_features,
    extract_features_and_joints,
    feature_slices,
    mirror_features,
    mirror_joints,
    recover_from_ric,
    recover_from_rot,
    recover_root_rot_pos,
)
from motionaug.augment.motion.kinematics import (
    forward_kinematics,
    forward_kinematics_cont6d,
    gaussian_smooth_time,
    inverse_kinematics,
    t2m_target_offsets,
    target_offsets,
    uniform_skeleton,
)
from motionaug.augment.motion.rotations import axis_angle_to_quat, euler_to_quat, qmul, quat_to_cont6d
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import KIT, T2M, Skeleton

torch.set_num_threads(1)
FIXTURES = Path(__file__).resolve().parent / "fixtures" / "humanml3d"
CLIP = "012314.npy"


@pytest.fixture(scope="module")
def dataset_vecs() -> np.ndarray:
    return np.load(FIXTURES / "new_joint_vecs" / CLIP)


@pytest.fixture(scope="module")
def dataset_joints() -> np.ndarray:
    return np.load(FIXTURES / "new_joints" / CLIP)


def synthetic_motion(skeleton: Skeleton, offsets: np.ndarray, n_frames: int = 60, seed: int = 0) -> np.ndarray:
    """Plausible motion: FK of smooth random joint rotations (<= 0.35 rad), a gentle yaw, a walk forward."""
    rng = np.random.default_rng(seed)
    t = torch.linspace(0.0, 1.0, n_frames, dtype=torch.float64)[:, None, None]
    freq = torch.as_tensor(rng.uniform(0.5, 2.0, (1, skeleton.n_joints, 3)))
    phase = torch.as_tensor(rng.uniform(0.0, 2 * math.pi, (1, skeleton.n_joints, 3)))
    local = axis_angle_to_quat(0.35 * torch.sin(2 * math.pi * freq * t + phase))
    tt = t[:, 0, 0]
    yaw_pitch_roll = torch.stack([0.9 * torch.sin(math.pi * tt), 0.1 * torch.sin(3 * tt), 0.05 * torch.cos(2 * tt)], -1)
    root = euler_to_quat(yaw_pitch_roll, "yxz")
    local = torch.cat([root[:, None], local[:, 1:]], dim=1)
    root_pos = torch.stack([0.8 * tt + 0.3, 0.95 + 0.03 * torch.sin(8 * tt), 1.2 * tt - 0.5], -1)
    return forward_kinematics(skeleton, offsets, local, root_pos).numpy()


def symmetric_offsets(skeleton: Skeleton, offsets: np.ndarray) -> np.ndarray:
    """Left/right-averaged offsets, so that mirroring a clip keeps its bone lengths."""
    mirrored = (offsets * np.array([-1.0, 1.0, 1.0]))[skeleton.mirror_permutation]
    return 0.5 * (offsets + mirrored)


def kit_offsets() -> np.ndarray:
    lengths = np.full(KIT.n_joints, 0.15)
    lengths[[5, 8]] = 0.2  # shoulders wider than hips keeps the reference IK's facing well defined
    lengths[[12, 13, 17, 18]] = 0.42
    return np.asarray(KIT.raw_offsets, dtype=np.float64) * lengths[:, None]


# ---- kinematics -----------------------------------------------------------------------------


def test_shipped_t2m_offsets_equal_reference_clip_frame0() -> None:
    joints = np.load(FIXTURES / "joints" / "000021.npy")[0, :22]
    parents = T2M.parents
    raw = np.asarray(T2M.raw_offsets, dtype=np.float64)
    # the reference: raw direction times bone length, computed in float32 (``get_offsets_joints``)
    expected = np.stack([raw[0]] + [np.linalg.norm(joints[i] - joints[parents[i]]) * raw[i] for i in range(1, 22)])
    shipped = t2m_target_offsets()
    assert shipped.shape == (22, 3) and shipped.dtype == np.float64
    np.testing.assert_allclose(shipped, expected.astype(np.float32), atol=1e-7)
    np.testing.assert_allclose(target_offsets(T2M, joints).numpy(), shipped, atol=1e-12)


def test_fk_inverts_ik_and_cont6d_fk_agrees() -> None:
    offsets = t2m_target_offsets()
    joints = synthetic_motion(T2M, offsets, n_frames=30, seed=1)
    quats = inverse_kinematics(T2M, joints)
    assert quats.shape == (30, 22, 4)
    torch.testing.assert_close(quats[0, 0], torch.tensor([1.0, 0, 0, 0], dtype=torch.float64))
    again = forward_kinematics(T2M, offsets, quats, torch.as_tensor(joints[:, 0]))
    np.testing.assert_allclose(again.numpy(), joints, atol=1e-9)
    via6d = forward_kinematics_cont6d(T2M, offsets, quat_to_cont6d(quats), torch.as_tensor(joints[:, 0]))
    np.testing.assert_allclose(via6d.numpy(), joints, atol=1e-9)


def test_fk_is_chainwise_from_the_root() -> None:
    """Arm chains start from the root rotation, not from spine3's: rotating the root alone moves them rigidly."""
    offsets = t2m_target_offsets()
    quats = torch.zeros(1, 22, 4, dtype=torch.float64)
    quats[..., 0] = 1.0
    quats[0, 9] = axis_angle_to_quat(torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))  # bend spine3
    joints = forward_kinematics(T2M, offsets, quats, torch.zeros(1, 3, dtype=torch.float64))[0]
    # spine3's own rotation affects the neck chain (12, 15) but not the arm chains hanging off joint 9
    np.testing.assert_allclose((joints[14] - joints[9]).numpy(), offsets[14], atol=1e-12)
    assert not np.allclose((joints[12] - joints[9]).numpy(), offsets[12])


def test_fk_batches_over_leading_dims() -> None:
    offsets = t2m_target_offsets()
    clips = [synthetic_motion(T2M, offsets, n_frames=8, seed=s) for s in (2, 3)]
    quats = torch.stack([inverse_kinematics(T2M, c) for c in clips])  # (2, 8, 22, 4)
    roots = torch.as_tensor(np.stack([c[:, 0] for c in clips]))
    batched = forward_kinematics(T2M, torch.as_tensor(offsets), quats, roots)
    assert batched.shape == (2, 8, 22, 3)
    np.testing.assert_allclose(batched.numpy(), np.stack(clips), atol=1e-9)
    torch.testing.assert_close(inverse_kinematics(T2M, torch.as_tensor(np.stack(clips))), quats)


def test_forward_smoothing_matches_scipy() -> None:
    from scipy import ndimage

    x = np.random.default_rng(0).normal(size=(50, 3))  # shorter than the 80-frame radius: edges repeat
    ours = gaussian_smooth_time(torch.as_tensor(x), 20.0, time_dim=0).numpy()
    np.testing.assert_allclose(ours, ndimage.gaussian_filter1d(x, 20, axis=0, mode="nearest"), atol=1e-12)


def test_uniform_skeleton_imposes_target_bone_lengths() -> None:
    target = t2m_target_offsets()
    source = synthetic_motion(T2M, target * 1.3, n_frames=20, seed=4)  # a 30% taller person
    out = uniform_skeleton(T2M, source, target).numpy()
    parents = T2M.parents
    for i in range(1, 22):
        bone = np.linalg.norm(out[:, i] - out[:, parents[i]], axis=-1)
        np.testing.assert_allclose(bone, np.linalg.norm(target[i]), atol=1e-9)
        direction = (source[:, i] - source[:, parents[i]]) / (1.3 * np.linalg.norm(target[i]))
        np.testing.assert_allclose((out[:, i] - out[:, parents[i]]) / np.linalg.norm(target[i]), direction, atol=1e-9)
    np.testing.assert_allclose(out[:, 0], source[:, 0] / 1.3, atol=1e-9)


# ---- features vs the real dataset -----------------------------------------------------------


def test_feature_slices_cover_the_vector() -> None:
    slices = feature_slices(T2M)
    assert list(slices) == list(FEATURE_BLOCKS)
    assert slices["ric"] == slice(4, 67) and slices["rot"] == slice(67, 193)
    assert slices["local_vel"] == slice(193, 259) and slices["feet"] == slice(259, 263)
    assert feature_slices(KIT)["feet"].stop == KIT.feature_dim == 251


def test_recover_from_ric_reproduces_dataset_joints(dataset_vecs: np.ndarray, dataset_joints: np.ndarray) -> None:
    recovered = recover_from_ric(torch.from_numpy(dataset_vecs), 22)
    assert recovered.dtype == torch.float32 and recovered.shape == (170, 22, 3)
    assert np.abs(recovered.numpy() - dataset_joints).max() < 1e-4


def test_recover_from_rot_agrees_with_ric_on_dataset(dataset_vecs: np.ndarray, dataset_joints: np.ndarray) -> None:
    from_rot = recover_from_rot(torch.from_numpy(dataset_vecs).double(), 22, T2M, t2m_target_offsets())
    assert np.abs(from_rot.numpy() - dataset_joints).max() < 1e-4


def test_recover_batches_over_leading_dims(dataset_vecs: np.ndarray) -> None:
    data = torch.from_numpy(dataset_vecs)
    batch = torch.stack([data[:50], data[60:110]])
    out = recover_from_ric(batch, 22)
    torch.testing.assert_close(out[1], recover_from_ric(data[60:110], 22))
    rot, pos = recover_root_rot_pos(batch)
    assert rot.shape == (2, 50, 4) and pos.shape == (2, 50, 3)
    torch.testing.assert_close(recover_from_rot(batch, 22)[0], recover_from_rot(data[:50], 22))
    with pytest.raises(MotionDataError, match="263"):
        recover_from_ric(data[:, :200], 22)


def test_extraction_round_trips_real_clip(dataset_joints: np.ndarray) -> None:
    result = extract_features_and_joints(dataset_joints)
    assert result.features.shape == (169, 263) and result.features.dtype == np.float32
    assert result.joints.shape == (170, 22, 3)
    recovered = recover_from_ric(torch.from_numpy(result.features).double(), 22).numpy()
    assert np.abs(recovered - result.joints[:-1]).max() < 1e-4
    from_rot = recover_from_rot(torch.from_numpy(result.features).double(), 22).numpy()
    assert np.abs(from_rot - recovered).max() < 1e-4


def test_extraction_matches_dataset_features(dataset_joints: np.ndarray, dataset_vecs: np.ndarray) -> None:
    """Re-extracting new_joints reproduces new_joint_vecs, row 0 (the frame-0 root reset) included.

    The dataset was extracted from raw joints one frame longer; only the last ~80 rows (the
    facing-smoothing radius) see that, so they get a looser bound.
    """
    features = extract_features(dataset_joints)
    reference = dataset_vecs[: len(features)]
    head = slice(0, len(features) - 80)
    for name, block in feature_slices(T2M).items():
        assert np.abs(features[head, block] - reference[head, block]).max() < 5e-5, name
        assert np.abs(features[:, block] - reference[:, block]).max() < 2e-2, name
    assert np.array_equal(features[:, -4:], reference[:, -4:])
    assert abs(features[0, 0] - reference[0, 0]) < 1e-5 and abs(reference[0, 0]) > 0.05


def test_extraction_round_trips_synthetic_motion() -> None:
    joints = synthetic_motion(T2M, t2m_target_offsets() * 1.1, n_frames=60, seed=5)
    result = extract_features_and_joints(joints)
    recovered = recover_from_ric(torch.from_numpy(result.features).double(), 22).numpy()
    assert np.abs(recovered - result.joints[:-1]).max() < 1e-4
    from_rot = recover_from_rot(torch.from_numpy(result.features).double(), 22).numpy()
    assert np.abs(from_rot - recovered).max() < 1e-4
    # canonical: on the floor, root at the XZ origin on frame 0
    assert abs(result.joints[..., 1].min()) < 1e-9
    np.testing.assert_allclose(result.joints[0, 0, [0, 2]], 0.0, atol=1e-9)


def test_extraction_is_generic_over_skeletons() -> None:
    offsets = kit_offsets()
    joints = synthetic_motion(KIT, offsets, n_frames=40, seed=6)
    result = extract_features_and_joints(joints, KIT, target_offsets=offsets)
    assert result.features.shape == (39, 251)
    recovered = recover_from_ric(torch.from_numpy(result.features).double(), KIT.n_joints).numpy()
    assert np.abs(recovered - result.joints[:-1]).max() < 1e-4
    with pytest.raises(ValueError, match="target_offsets"):
        extract_features(joints, KIT)


def test_foot_contacts_follow_the_threshold() -> None:
    joints = synthetic_motion(T2M, t2m_target_offsets(), n_frames=20, seed=7)
    still = np.repeat(joints[:1], 20, axis=0)
    assert extract_features(still)[:, -4:].min() == 1.0
    assert extract_features(still, feet_threshold=0.0)[:, -4:].max() == 0.0


@pytest.mark.parametrize(
    ("joints", "reason"),
    [
        (np.zeros((10, 21, 3)), "must be"),
        (np.zeros((1, 22, 3)), "at least 2 frames"),
        (np.full((5, 22, 3), np.nan), "NaN"),
        (np.zeros((5, 22, 3)), "degenerate"),
    ],
)
def test_bad_joints_raise_motion_data_error(joints: np.ndarray, reason: str) -> None:
    with pytest.raises(MotionDataError, match=reason) as err:
        extract_features(joints, source="clip_x.npy")
    assert str(err.value).startswith("clip_x.npy: ")


# ---- mirroring -------------------------------------------------------------------------------


def test_mirroring_twice_is_identity(dataset_vecs: np.ndarray, dataset_joints: np.ndarray) -> None:
    np.testing.assert_array_equal(mirror_features(mirror_features(dataset_vecs)), dataset_vecs)
    np.testing.assert_array_equal(mirror_joints(mirror_joints(dataset_joints)), dataset_joints)
    as_torch = torch.from_numpy(dataset_vecs)
    torch.testing.assert_close(mirror_features(mirror_features(as_torch)), as_torch)
    assert not np.allclose(mirror_features(dataset_vecs), dataset_vecs)


def test_mirrored_features_recover_to_mirrored_joints(dataset_vecs: np.ndarray) -> None:
    data = torch.from_numpy(dataset_vecs).double()
    expected = mirror_joints(recover_from_ric(data, 22))
    torch.testing.assert_close(recover_from_ric(mirror_features(data), 22), expected, atol=1e-9, rtol=0)
    from_rot = recover_from_rot(mirror_features(data), 22, T2M, symmetric_offsets(T2M, t2m_target_offsets()))
    expected_rot = mirror_joints(recover_from_rot(data, 22, T2M, symmetric_offsets(T2M, t2m_target_offsets())))
    torch.testing.assert_close(from_rot, expected_rot, atol=1e-9, rtol=0)


def test_mirror_features_equals_extracting_mirrored_joints() -> None:
    """Channel-wise mirroring is what re-extraction gives, for a rig whose two sides match."""
    offsets = symmetric_offsets(T2M, t2m_target_offsets())
    joints = extract_features_and_joints(
        synthetic_motion(T2M, offsets, n_frames=40, seed=8), target_offsets=offsets
    ).joints
    direct = extract_features(mirror_joints(joints), target_offsets=offsets)
    np.testing.assert_allclose(mirror_features(extract_features(joints, target_offsets=offsets)), direct, atol=1e-5)


def test_mirror_rejects_asymmetric_rig() -> None:
    lopsided = Skeleton.model_validate({**T2M.model_dump(), "mirror_pairs": [(1, 2)]})
    with pytest.raises(ValueError, match="left_knee has no mirror image"):
        mirror_features(np.zeros((2, 263), dtype=np.float32), lopsided)
    wrong_feet = Skeleton.model_validate({**T2M.model_dump(), "feet_right": (8, 10)})
    with pytest.raises(ValueError, match="feet"):
        mirror_features(np.zeros((2, 263), dtype=np.float32), wrong_feet)


# ---- Mean / Std ------------------------------------------------------------------------------


def test_dataset_std_is_constant_within_our_blocks() -> None:
    """The released Std.npy has exactly our block structure: one value per block, distinct neighbours."""
    norm = Normalizer.load(FIXTURES)
    assert norm.mean.shape == norm.std.shape == (263,)
    values = [norm.std[block] for block in feature_slices(T2M).values()]
    assert all(np.ptp(v) == 0 for v in values)
    assert all(a[0] != b[0] for a, b in zip(values[:-1], values[1:]))


def test_shared_mean_std_load() -> None:
    norm = Normalizer.load(FIXTURES)
    assert norm.mean.shape == norm.std.shape == (263,) and norm.mean.dtype == np.float32


def test_compute_mean_std_follows_reference(dataset_vecs: np.ndarray) -> None:
    clips = [dataset_vecs[:70], dataset_vecs[70:], mirror_features(dataset_vecs)]
    norm = compute_mean_std(iter(clips))
    data = np.concatenate(clips).astype(np.float64)
    np.testing.assert_allclose(norm.mean, data.mean(0), rtol=1e-6, atol=1e-7)
    std = data.std(0)
    for block in feature_slices(T2M).values():
        np.testing.assert_allclose(norm.std[block], std[block].mean(), rtol=1e-6)
    assert norm.std[0] != norm.std[1]


def test_compute_mean_std_rejects_bad_clips(dataset_vecs: np.ndarray) -> None:
    bad = dataset_vecs.copy()
    bad[3, 5] = np.nan
    with pytest.raises(MotionDataError, match="clip 1"):
        compute_mean_std([dataset_vecs, bad])
    with pytest.raises(MotionDataError, match="263"):
        compute_mean_std([dataset_vecs[:, :10]])
    with pytest.raises(MotionDataError, match="no clips"):
        compute_mean_std([])
    flat_height = dataset_vecs.copy()
    flat_height[:, 3] = 0.9
    with pytest.raises(MotionDataError, match="block root_y is constant"):
        compute_mean_std([flat_height])


def test_normalizer_round_trip_numpy_torch_and_files(dataset_vecs: np.ndarray, tmp_path: Path) -> None:
    norm = Normalizer.load(FIXTURES)
    z = norm.normalize(dataset_vecs)
    np.testing.assert_allclose(norm.denormalize(z), dataset_vecs, atol=1e-5)
    zt = norm.normalize(torch.from_numpy(dataset_vecs))
    assert isinstance(zt, torch.Tensor) and zt.dtype == torch.float32
    np.testing.assert_allclose(zt.numpy(), z, atol=1e-6)
    norm.save(tmp_path)
    again = Normalizer.load(tmp_path)
    np.testing.assert_array_equal(again.mean, norm.mean)
    np.testing.assert_array_equal(again.std, norm.std)
    with pytest.raises(MotionDataError, match="does not match"):
        norm.normalize(np.zeros((2, 10)))


def test_normalizer_rejects_bad_statistics(tmp_path: Path) -> None:
    with pytest.raises(MotionDataError, match="positive"):
        Normalizer(np.zeros(4), np.array([1.0, 0.0, 1.0, 1.0]))
    with pytest.raises(MotionDataError, match="equal"):
        Normalizer(np.zeros(4), np.ones(5))
    with pytest.raises(MotionDataError, match="not found"):
        Normalizer.load(tmp_path)
    (tmp_path / "Mean.npy").write_text("not numpy")
    (tmp_path / "Std.npy").write_text("not numpy")
    with pytest.raises(MotionDataError, match="Mean.npy"):
        Normalizer.load(tmp_path)


def test_quaternion_root_helpers_are_consistent() -> None:
    """The recovered root yaw composes: half-angle velocity integrates to the same rotation as qmul."""
    data = torch.zeros(5, 263, dtype=torch.float64)
    data[:, 0] = 0.1
    rot, _ = recover_root_rot_pos(data)
    step = rot[1]
    torch.testing.assert_close(qmul(step, step), rot[2])


def test_extraction_round_trips_a_curved_walk_through_180_degrees() -> None:
    """Turning through 180 degrees: the reference's asin(y) flipped one frame's turn; ours must not."""
    from motionaug.augment.synth.animator import ClipSpec, render

    clip = render(ClipSpec(content="walk_curve", duration=6, curvature=0.7))
    ex = extract_features_and_joints(clip.joints)
    back = recover_from_ric(torch.from_numpy(ex.features).double(), 22).numpy()
    assert np.abs(back - ex.joints[:-1]).max() < 1e-4
