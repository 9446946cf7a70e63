"""Foot locking (a planted toe stops sliding, poses stay, the velocity channels stay consistent) and foot planting
(planted toes held by moving the legs, bones kept, swing clearance)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from motionaug.augment.methods.shapers import toe_contacts
from motionaug.augment.metrics import foot_skating_ratio
from motionaug.augment.motion.features import feature_slices, recover_from_ric, recover_root_rot_pos
from motionaug.augment.motion.foot_lock import lock_feet, plant_feet
from motionaug.schemas.skeleton import T2M

CLIP = Path(__file__).resolve().parent / "fixtures" / "humanml3d" / "new_joint_vecs" / "012314.npy"
BLOCKS = feature_slices(T2M)


def joints(features: np.ndarray) -> np.ndarray:
    return recover_from_ric(torch.as_tensor(features, dtype=torch.float64), T2M.n_joints).numpy()


def skating(features: np.ndarray) -> float:
    return foot_skating_ratio(joints(features), T2M, 20.0)


def sliding_clip() -> np.ndarray:
    """The dataset clip with its root path stretched: the path no longer matches the legs."""
    features = np.load(CLIP).astype(np.float32)
    features[:, BLOCKS["root_lin_vel"]] *= 1.8
    return features


def test_planted_toe_stops_sliding() -> None:
    features = sliding_clip()
    locked = lock_feet(features)
    assert locked.dtype == features.dtype and locked.shape == features.shape
    assert skating(locked) < 0.5 * skating(features)
    pos = joints(locked)
    toes = pos[:, [T2M.feet_left[1], T2M.feet_right[1]]]
    planted = (toes[1:, :, 1] < 0.05) & (toes[:-1, :, 1] < 0.05)
    slide = np.linalg.norm((toes[1:] - toes[:-1])[..., [0, 2]], axis=-1)
    held = np.where(planted.all(-1), slide.min(-1), np.where(planted[:, 0], slide[:, 0], slide[:, 1]))
    assert held[planted.any(-1)].max() < 1e-4  # the held toe of every planted transition stays put


def test_poses_are_untouched_and_local_velocities_follow_the_new_path() -> None:
    features = sliding_clip()
    locked = lock_feet(features)
    for block in ("root_rot_vel", "root_y", "ric", "rot", "feet"):
        np.testing.assert_array_equal(locked[:, BLOCKS[block]], features[:, BLOCKS[block]])
    shift = (locked - features)[:-1, BLOCKS["local_vel"]].reshape(len(features) - 1, T2M.n_joints, 3)
    np.testing.assert_allclose(shift, np.broadcast_to(shift[:, :1], shift.shape), atol=1e-6)  # every joint alike

    def root_steps(f: np.ndarray) -> np.ndarray:
        return np.diff(recover_root_rot_pos(torch.as_tensor(f, dtype=torch.float64))[1].numpy(), axis=0)

    moved = root_steps(locked) - root_steps(features)  # the world-frame change of each root step
    np.testing.assert_allclose(np.linalg.norm(shift[:, 0], axis=-1), np.linalg.norm(moved, axis=-1), atol=1e-5)
    assert np.abs(moved).max() > 0.01  # the stretched path was corrected


def test_a_clip_whose_feet_do_not_slide_keeps_its_planted_toes_still() -> None:
    features = np.load(CLIP).astype(np.float32)
    assert skating(lock_feet(features)) <= skating(features) + 1e-9
    assert lock_feet(features[:1]).shape == (1, features.shape[1])


def wobbly_legs(features: np.ndarray) -> np.ndarray:
    """The clip with its left ankle and toe swayed sideways in the root frame: planted toes slide, the knee stays."""
    out = features.copy()
    ric = out[:, BLOCKS["ric"]].reshape(len(out), T2M.n_joints - 1, 3)
    sway = 0.06 * np.sin(np.arange(len(out)) / 3.0)
    for joint in T2M.feet_left:
        ric[:, joint - 1, 0] += sway
    out[:, BLOCKS["ric"]] = ric.reshape(len(out), -1)
    return out


def leg_bones(pos: np.ndarray, ankle: int) -> tuple[int, int, int]:
    knee = T2M.parents[ankle]
    return T2M.parents[knee], knee, ankle


def test_plant_feet_holds_each_planted_toe_within_reach_and_keeps_the_legs_bones() -> None:
    clean = np.load(CLIP).astype(np.float32)
    contacts = toe_contacts(clean)
    features = wobbly_legs(clean)
    planted = plant_feet(features, contacts, blend=2)
    assert planted.shape == features.shape and planted.dtype == features.dtype
    pos, before = joints(planted), joints(features)
    held, frames = 0, 0
    for (ankle, toe), flags in zip((T2M.feet_left, T2M.feet_right), contacts.T):
        hip, knee, _ = leg_bones(pos, ankle)
        lengths = {b: np.linalg.norm(before[:, b] - before[:, a], axis=-1) for a, b in ((hip, knee), (knee, ankle))}
        reach = sum(v.mean() for v in lengths.values()) - np.linalg.norm(pos[:, ankle] - pos[:, hip], axis=-1)
        edges = np.flatnonzero(np.diff(flags.astype(int))) + 1
        for run in (r for r in np.split(np.arange(len(flags)), edges) if flags[r[0]]):
            place = pos[run][:, toe, [0, 2]]
            still = np.abs(place - np.median(place, axis=0)).max(-1) < 1e-4  # the toe stays put over its run
            assert still[reach[run] > 1e-3].all()  # wherever the leg can reach, that is
            held, frames = held + still.sum(), frames + len(run)
        for a, b in ((hip, knee), (knee, ankle), (ankle, toe)):
            after = np.linalg.norm(pos[:, b] - pos[:, a], axis=-1)
            np.testing.assert_allclose(after, np.linalg.norm(before[:, b] - before[:, a], axis=-1).mean(), atol=2e-3)
    assert held > 0.9 * frames
    assert skating(planted) < skating(features)
    others = np.setdiff1d(np.arange(features.shape[1]), np.arange(BLOCKS["ric"].start, BLOCKS["ric"].stop))
    np.testing.assert_array_equal(planted[:, others], features[:, others])  # only the joint positions change


def test_plant_feet_raises_a_swinging_toe_to_its_clearance_only() -> None:
    clean = np.load(CLIP).astype(np.float32)
    contacts = toe_contacts(clean)
    toes = [T2M.feet_left[1], T2M.feet_right[1]]
    floor = joints(clean)[:, toes, 1] + 0.03  # 3 cm above the clip's own toes
    lifted = joints(plant_feet(clean, contacts, clearance=floor))[:, toes, 1]
    assert (lifted[~contacts] >= floor[~contacts] - 1e-4).all()
    held = joints(plant_feet(clean, contacts))[:, toes, 1]
    np.testing.assert_allclose(lifted[contacts], held[contacts], atol=1e-4)  # planted toes: as without clearance
