"""BVH reading/writing and retargeting onto t2m joints, on real Bandai Namco clips."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import require_shared

from motionaug.augment.motion.bvh import (
    BvhMotion,
    euler_to_matrix,
    forward_kinematics,
    joints_to_bvh,
    matrix_to_euler,
    matrix_to_quat,
    quat_to_matrix,
    read_bvh,
    write_bvh,
)
from motionaug.augment.motion.retarget import (
    BANDAI_TO_T2M,
    JointMap,
    labels_from_bandai,
    load_bvh_as_t2m_joints,
    nominal_fps,
    resample,
    retarget_positions,
)
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import T2M

FIXTURES = Path(__file__).resolve().parent / "fixtures" / "bvh"
WALK = FIXTURES / "dataset-1" / "data" / "dataset-1_walk_normal_002.bvh"
DASH = FIXTURES / "dataset-1" / "data" / "dataset-1_dash_normal_001.bvh"
RAISE = FIXTURES / "dataset-2" / "data" / "dataset-2_raise-up-left-hand_active_003.bvh"
J = {name: i for i, name in enumerate(T2M.joint_names)}


def _fixture_lines(path: Path) -> list[str]:
    return path.read_text().splitlines()


def _motion_line(lines: list[str]) -> int:
    return next(i for i, ln in enumerate(lines) if ln.strip() == "MOTION")


# --------------------------------------------------------------------------- reader


def test_reads_bandai_fixture() -> None:
    motion = read_bvh(WALK)
    assert motion.n_joints == 22 and motion.names[0] == "joint_Root" and motion.names[1] == "Hips"
    assert all(len(c) == 6 for c in motion.channels)
    assert motion.channels[1][3:] == ("Zrotation", "Xrotation", "Yrotation")
    assert motion.frames.shape == (31, 132) and motion.frames.dtype == np.float64
    assert nominal_fps(motion.frame_time) == 30.0
    assert all(p < j for j, p in enumerate(motion.parents))
    assert motion.parents[motion.names.index("Hand_L")] == motion.names.index("LowerArm_L")
    assert len(motion.end_sites) == 5  # head, two hands, two toes
    pos = motion.global_positions()
    assert pos.shape == (31, 22, 3) and np.isfinite(pos).all()


def test_whitespace_crlf_and_tabs(tmp_path: Path) -> None:
    text = WALK.read_text()
    odd = tmp_path / "odd.bvh"
    odd.write_bytes(("\ufeff" + text.replace(" ", " \t ").replace("\n", "\r\n\r\n")).encode("utf-8"))
    a, b = read_bvh(WALK), read_bvh(odd)
    assert a.names == b.names and np.array_equal(a.frames, b.frames) and np.array_equal(a.offsets, b.offsets)


def test_rest_pose_is_cumulative_offsets(tmp_path: Path) -> None:
    """All-zero channels: every joint sits at the sum of the offsets down its chain (T-pose check)."""
    bvh = """HIERARCHY
ROOT hips
{
  OFFSET 1 2 3
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT spine
  {
    OFFSET 0 10 0
    CHANNELS 3 Xrotation Yrotation Zrotation
    JOINT left arm
    {
      OFFSET 20 0 0
      CHANNELS 2 Yrotation Zrotation
      End Site
      {
        OFFSET 5 0 0
      }
    }
  }
  JOINT leg
  {
    OFFSET 0 -40 1
    End Site
    {
      OFFSET 0 -1 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.01
0 0 0 0 0 0 0 0 0 0 0
1 2 3 0 0 0 0 90 0 0 90
"""
    path = tmp_path / "rest.bvh"
    path.write_text(bvh)
    motion = read_bvh(path)
    assert motion.names == ["hips", "spine", "left arm", "leg"] and motion.channels[3] == ()
    assert motion.fps == pytest.approx(100.0)
    pos = motion.global_positions()
    np.testing.assert_allclose(pos[0], [[0, 0, 0], [0, 10, 0], [20, 10, 0], [0, -40, 1]], atol=1e-12)
    # Frame 1: root moved to (1,2,3); spine yawed 90 deg about Y then arm rolled about Z (no effect on its origin).
    np.testing.assert_allclose(pos[1, 2], [1, 12, 3 - 20], atol=1e-9)
    np.testing.assert_allclose(motion.end_sites[2], [5, 0, 0])


def test_euler_order_is_intrinsic_channel_order() -> None:
    angles = np.array([30.0, -50.0, 75.0])
    rot = euler_to_matrix(angles, "ZXY")
    rz = euler_to_matrix(np.array([30.0, 0, 0]), "ZXY")
    rx = euler_to_matrix(np.array([0, -50.0, 0]), "ZXY")
    ry = euler_to_matrix(np.array([0, 0, 75.0]), "ZXY")
    np.testing.assert_allclose(rot, rz @ rx @ ry, atol=1e-12)
    np.testing.assert_allclose(rz @ [1.0, 0, 0], [np.cos(np.pi / 6), np.sin(np.pi / 6), 0], atol=1e-12)


@pytest.mark.parametrize("order", ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"])
def test_rotation_conversions_round_trip(order: str) -> None:
    rng = np.random.default_rng(0)
    quats = rng.normal(size=(200, 4))
    quats[:3] = [[1, 0, 0, 0], [0.5, 0.5, 0.5, 0.5], [np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)]]
    rot = quat_to_matrix(quats)
    back = euler_to_matrix(matrix_to_euler(rot, order), order)
    np.testing.assert_allclose(back, rot, atol=1e-9)
    np.testing.assert_allclose(quat_to_matrix(matrix_to_quat(rot)), rot, atol=1e-12)
    # Gimbal lock: middle angle +-90 deg must still reproduce the matrix.
    locked = euler_to_matrix(np.array([[40.0, 90.0, 10.0], [-70.0, -90.0, 25.0]]), order)
    np.testing.assert_allclose(euler_to_matrix(matrix_to_euler(locked, order), order), locked, atol=1e-9)


# --------------------------------------------------------------------------- corrupted files


def _corrupt(tmp_path: Path, name: str, lines: list[str]) -> Path:
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


def test_truncated_file_raises(tmp_path: Path) -> None:
    lines = _fixture_lines(WALK)
    path = _corrupt(tmp_path, "truncated.bvh", lines[:-5])
    with pytest.raises(MotionDataError, match=r"truncated: header says 31 frames, found 26") as err:
        read_bvh(path)
    assert err.value.source == str(path) and "truncated.bvh" in str(err.value)


def test_cut_mid_line_names_the_line(tmp_path: Path) -> None:
    lines = _fixture_lines(WALK)
    last = lines[-1].split()
    path = _corrupt(tmp_path, "cut.bvh", lines[:-1] + [" ".join(last[:60])])
    with pytest.raises(MotionDataError, match=rf"line {len(lines)}: expected 132 channel values, found 60"):
        read_bvh(path)


def test_garbled_number_names_the_line(tmp_path: Path) -> None:
    lines = _fixture_lines(WALK)
    row = _motion_line(lines) + 10
    lines[row] = " ".join(lines[row].split()[:5] + ["1.2.3x"] + lines[row].split()[6:])
    with pytest.raises(MotionDataError, match=rf"line {row + 1}: '1.2.3x' is not a number"):
        read_bvh(_corrupt(tmp_path, "garbled.bvh", lines))
    lines[row] = " ".join(["nan"] + _fixture_lines(WALK)[row].split()[1:])
    with pytest.raises(MotionDataError, match=rf"line {row + 1}: non-finite"):
        read_bvh(_corrupt(tmp_path, "nan.bvh", lines))


def test_missing_motion_section_and_bad_headers(tmp_path: Path) -> None:
    lines = _fixture_lines(WALK)
    motion = _motion_line(lines)
    with pytest.raises(MotionDataError, match="no MOTION section"):
        read_bvh(_corrupt(tmp_path, "nomotion.bvh", lines[:motion]))
    bad_frames = lines.copy()
    bad_frames[motion + 1] = "Frames: many"
    with pytest.raises(MotionDataError, match="frame count 'many'"):
        read_bvh(_corrupt(tmp_path, "frames.bvh", bad_frames))
    extra = lines + [lines[-1]]
    with pytest.raises(MotionDataError, match="header says 31 frames, found 32 frame lines"):
        read_bvh(_corrupt(tmp_path, "extra.bvh", extra))


def test_wrong_channel_count_and_broken_hierarchy(tmp_path: Path) -> None:
    lines = _fixture_lines(WALK)
    first = next(i for i, ln in enumerate(lines) if "CHANNELS" in ln and i > 5)
    fewer = lines.copy()
    fewer[first] = fewer[first].replace("CHANNELS 6 Xposition Yposition Zposition", "CHANNELS 3")
    with pytest.raises(MotionDataError, match=r"expected 129 channel values, found 132"):
        read_bvh(_corrupt(tmp_path, "channels.bvh", fewer))
    unknown = lines.copy()
    unknown[first] = unknown[first].replace("Zrotation", "Wrotation")
    with pytest.raises(MotionDataError, match=rf"line {first + 1}: unknown channel 'Wrotation'"):
        read_bvh(_corrupt(tmp_path, "unknown.bvh", unknown))
    unclosed = lines.copy()
    unclosed[first - 2] = ""  # the "{" after "JOINT Hips"
    with pytest.raises(MotionDataError, match=rf"line {first}: expected '{{', found 'OFFSET'"):
        read_bvh(_corrupt(tmp_path, "braces.bvh", unclosed))
    for name, data in [("empty.bvh", b""), ("binary.bvh", b"\xff\xfe\x00garbage")]:
        (tmp_path / name).write_bytes(data)
        with pytest.raises(MotionDataError, match="empty file|not a text file"):
            read_bvh(tmp_path / name)
    with pytest.raises(MotionDataError, match="cannot read file"):
        read_bvh(tmp_path / "absent.bvh")


# --------------------------------------------------------------------------- writer


def test_write_read_round_trip(tmp_path: Path) -> None:
    motion = read_bvh(RAISE)
    path = write_bvh(
        tmp_path / "out" / "rt.bvh",
        motion.names,
        motion.parents,
        motion.offsets,
        motion.local_quaternions(),
        motion.local_translations()[:, 0],
        fps=30.0,
        order="YXZ",
        translations=motion.local_translations(),
    )
    back = read_bvh(path)
    assert back.names == motion.names and back.n_frames == motion.n_frames
    assert back.channels[1] == ("Xposition", "Yposition", "Zposition", "Yrotation", "Xrotation", "Zrotation")
    want = motion.global_positions()
    assert np.abs(back.global_positions() - want).max() < 1e-6 * np.abs(want).max()
    assert not list(path.parent.glob("*.tmp"))


def test_round_trip_of_a_rotation_only_rig(tmp_path: Path) -> None:
    """Random rotations on the t2m tree, written with the root as the only moving joint."""
    rng = np.random.default_rng(1)
    quats = rng.normal(size=(7, 22, 4))
    offsets = np.asarray(T2M.raw_offsets) * rng.uniform(5, 40, size=(22, 1))
    root = rng.normal(size=(7, 3)) * 100
    names = [n.upper() for n in T2M.joint_names]
    path = write_bvh(tmp_path / "rig.bvh", names, T2M.parents, offsets, quats, root, fps=12.5, order="XZY")
    back = read_bvh(path)
    assert back.fps == pytest.approx(12.5) and back.channels[1] == ("Xrotation", "Zrotation", "Yrotation")
    trans = np.broadcast_to(offsets, (7, 22, 3)).copy()
    trans[:, 0] = root
    want = forward_kinematics(T2M.parents, quat_to_matrix(quats), trans)[1]
    got = back.global_positions()[:, [back.names.index(n) for n in names]]
    assert np.abs(got - want).max() < 1e-6 * np.abs(want).max()


def test_writer_rejects_bad_input(tmp_path: Path) -> None:
    quats = np.tile([1.0, 0, 0, 0], (2, 2, 1))
    with pytest.raises(MotionDataError, match="exactly one root"):
        write_bvh(tmp_path / "a.bvh", ["a", "b"], [-1, -1], np.zeros((2, 3)), quats, np.zeros((2, 3)), 30)
    with pytest.raises(MotionDataError, match="local_quats"):
        write_bvh(tmp_path / "a.bvh", ["a", "b"], [-1, 0], np.zeros((2, 3)), quats[:, :1], np.zeros((2, 3)), 30)
    assert not (tmp_path / "a.bvh").exists()


def test_joints_to_bvh_round_trip(tmp_path: Path) -> None:
    joints = retarget_positions(read_bvh(DASH), BANDAI_TO_T2M)
    err = joints_to_bvh(tmp_path / "t2m.bvh", joints, fps=30)
    back = read_bvh(tmp_path / "t2m.bvh")
    assert back.names[0] == "pelvis" and set(back.names) == set(T2M.joint_names)
    assert back.fps == pytest.approx(30.0) and back.n_frames == len(joints)
    got = back.global_positions()[:, [back.names.index(n) for n in T2M.joint_names]]
    assert np.abs(got - joints).max() == pytest.approx(err, abs=1e-6)
    assert err < 1e-3  # spine2 (a blend across Bandai's Spine joint) flexes by ~1 mm
    with pytest.raises(MotionDataError, match=r"joints must be \(T, 22, 3\)"):
        joints_to_bvh(tmp_path / "bad.bvh", joints[:, :21])


def test_joints_to_bvh_is_exact_for_a_rigid_clip(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    offsets = np.asarray(T2M.raw_offsets) * rng.uniform(0.05, 0.4, size=(22, 1))
    offsets[[1, 2]] += [0, -0.08, 0.01]  # hips below and ahead of the pelvis: not the rest directions
    trans = np.broadcast_to(offsets, (9, 22, 3)).copy()
    trans[:, 0] = rng.normal(size=(9, 3))
    joints = forward_kinematics(T2M.parents, quat_to_matrix(rng.normal(size=(9, 22, 4))), trans)[1]
    assert joints_to_bvh(tmp_path / "rigid.bvh", joints) < 1e-9
    back = read_bvh(tmp_path / "rigid.bvh")
    got = back.global_positions()[:, [back.names.index(n) for n in T2M.joint_names]]
    assert np.abs(got - joints).max() < 1e-6


def test_joints_to_bvh_on_humanml3d_clip(tmp_path: Path) -> None:
    joints = np.load(FIXTURES.parent / "humanml3d" / "new_joints" / "012314.npy")
    err = joints_to_bvh(tmp_path / "hml.bvh", joints)
    back = read_bvh(tmp_path / "hml.bvh")
    got = back.global_positions()[:, [back.names.index(n) for n in T2M.joint_names]]
    assert err < 1e-3 and np.abs(got - joints).max() < 1e-3


# --------------------------------------------------------------------------- retargeting


def test_retargeted_bandai_clip_is_plausible() -> None:
    motion = read_bvh(WALK)
    joints = retarget_positions(motion, BANDAI_TO_T2M)
    assert joints.shape == (31, 22, 3)
    parents = T2M.parents
    bones = np.stack([np.linalg.norm(joints[:, j] - joints[:, parents[j]], axis=-1) for j in range(1, 22)], 1)
    assert bones.std(axis=0).max() < 1e-3  # rigid skeleton (rest check)
    for left, right in T2M.mirror_pairs:
        assert bones[:, left - 1].mean() == pytest.approx(bones[:, right - 1].mean(), abs=0.01)
    leg = bones[:, [J["left_knee"] - 1, J["left_ankle"] - 1]].sum(1).mean()
    assert 0.6 < leg < 1.1
    floor = joints[:, [J["left_foot"], J["right_foot"], J["left_ankle"], J["right_ankle"]], 1].min()
    assert -0.05 < floor < 0.15  # feet near the floor, Y up, metres
    height = joints[:, J["head"], 1].mean() - floor
    assert 1.2 < height < 2.0  # head *joint* (Bandai: base of the skull) above the floor
    assert (joints[:, J["spine1"], 1] > joints[:, J["pelvis"], 1]).all()


def test_retargeted_bandai_is_not_mirrored() -> None:
    """Facing taken from the feet (toes ahead of ankles), independent of left/right names."""
    for path in (WALK, DASH, RAISE):
        joints = retarget_positions(read_bvh(path), BANDAI_TO_T2M)
        toes, ankles = joints[:, [J["left_foot"], J["right_foot"]]], joints[:, [J["left_ankle"], J["right_ankle"]]]
        forward = (toes - ankles).sum(axis=1)
        forward = forward.mean(axis=0)  # the clip's facing; single frames of a dash swing the feet
        heading = np.arctan2(forward[0], forward[2])
        c, s = np.cos(-heading), np.sin(-heading)
        for left, right in [("left_hip", "right_hip"), ("left_shoulder", "right_shoulder")]:
            gap = joints[:, J[left]] - joints[:, J[right]]
            x_facing_z = c * gap[:, 0] + s * gap[:, 2]  # x of left - right after turning to face +Z
            assert (x_facing_z > 0).all(), (path.name, left)
    walk = retarget_positions(read_bvh(WALK), BANDAI_TO_T2M)
    travel = walk[-1, 0] - walk[0, 0]
    feet = (walk[:, J["left_foot"]] - walk[:, J["left_ankle"]]).mean(0)
    assert travel[[0, 2]] @ feet[[0, 2]] > 0  # walks the way its toes point


def test_resample_keeps_duration_and_values() -> None:
    t = np.arange(31) / 30.0
    pos = np.stack([t, t**2, np.sin(t)], -1)[:, None, :]  # (31, 1, 3)
    out = resample(pos, 30, 20)
    assert out.shape == (21, 1, 3)
    assert (len(out) - 1) / 20 == pytest.approx((len(pos) - 1) / 30)
    np.testing.assert_allclose(out[:, 0, 0], np.arange(21) / 20.0, atol=1e-12)  # linear is exact
    np.testing.assert_allclose(out[[0, -1]], pos[[0, -1]])
    assert resample(pos[:32], 30, 30).shape == pos.shape
    assert len(resample(np.zeros((128, 2)), 30, 20)) == 85  # floor(127 * 2 / 3) + 1
    with pytest.raises(ValueError):
        resample(pos, 0, 20)


def test_load_bvh_as_t2m_joints() -> None:
    joints, fps = load_bvh_as_t2m_joints(WALK)
    assert fps == 30.0 and joints.shape == (21, 22, 3)
    direct = retarget_positions(read_bvh(WALK), BANDAI_TO_T2M)
    np.testing.assert_allclose(joints[[0, -1]], direct[[0, -1]], atol=1e-9)


def test_unknown_skeleton_needs_a_map(tmp_path: Path) -> None:
    text = WALK.read_text().replace("Hips", "Pelvis")
    (tmp_path / "other.bvh").write_text(text)
    with pytest.raises(MotionDataError, match="no joint map for skeleton with joints"):
        load_bvh_as_t2m_joints(tmp_path / "other.bvh")
    with pytest.raises(MotionDataError, match="needs joints absent from the file"):
        retarget_positions(read_bvh(tmp_path / "other.bvh"), BANDAI_TO_T2M)
    # A user map fixes it; YAML and JSON both load, extra keys are rejected.
    data = BANDAI_TO_T2M.model_dump()
    data["joints"] = json.loads(json.dumps(data["joints"]).replace('"Hips"', '"Pelvis"'))
    (tmp_path / "map.json").write_text(json.dumps(data))
    joints, _ = load_bvh_as_t2m_joints(tmp_path / "other.bvh", tmp_path / "map.json")
    np.testing.assert_allclose(joints, load_bvh_as_t2m_joints(WALK)[0])
    import yaml

    (tmp_path / "map.yaml").write_text(yaml.safe_dump(data))
    assert JointMap.from_file(tmp_path / "map.yaml") == JointMap.from_file(tmp_path / "map.json")
    (tmp_path / "typo.json").write_text(json.dumps({**data, "scael": 1}))
    with pytest.raises(MotionDataError, match="typo.json: bad joint map: scael"):
        JointMap.from_file(tmp_path / "typo.json")


def test_joint_map_validation_and_axes() -> None:
    data = BANDAI_TO_T2M.model_dump()
    with pytest.raises(ValueError, match="sum to 0.9"):
        JointMap.model_validate({**data, "joints": {**data["joints"], "spine1": {"Hips": 0.4, "Spine": 0.5}}})
    with pytest.raises(ValueError, match=r"missing \['head'\]"):
        JointMap.model_validate({**data, "joints": {k: v for k, v in data["joints"].items() if k != "head"}})
    z_up = JointMap.model_validate({**data, "up_axis": "+z"}).axes()
    np.testing.assert_allclose(z_up @ [0, 0, 1.0], [0, 1, 0])
    assert np.linalg.det(z_up) == pytest.approx(1.0)
    left = JointMap.model_validate({**data, "handedness": "left"}).axes()
    assert np.linalg.det(left) == pytest.approx(-1.0)


def test_labels_from_bandai(tmp_path: Path) -> None:
    assert labels_from_bandai(WALK) == ("walk", "normal")
    assert labels_from_bandai(RAISE) == ("raise-up-left-hand", "active")
    lone = tmp_path / "dataset-2_wave-both-hands_elderly_017.bvh"  # no JSON: from the name
    lone.write_text("")
    assert labels_from_bandai(lone) == ("wave-both-hands", "elderly")
    with pytest.raises(MotionDataError, match="not dataset-N_"):
        labels_from_bandai(tmp_path / "clip.bvh")


# --------------------------------------------------------------------------- the whole shared set


def test_every_shared_bandai_file_parses() -> None:
    root = require_shared("bandai")
    files = sorted(root.glob("dataset-*/data/*.bvh"))
    empty = [f for f in files if f.stat().st_size == 0]
    assert [f.name for f in empty] == ["dataset-1_dance-long_normal_001.bvh"]  # missing upstream
    with pytest.raises(MotionDataError, match="empty file"):
        read_bvh(empty[0])
    bandai_names = read_bvh(WALK).names
    start = time.perf_counter()
    frames = 0
    for path in files:
        if path in empty:
            continue
        motion: BvhMotion = read_bvh(path)
        header = next(ln for ln in path.read_text().splitlines() if ln.startswith("Frames:"))
        assert motion.n_frames == int(header.split()[1]), path
        assert motion.names == bandai_names, path
        frames += motion.n_frames
    elapsed = time.perf_counter() - start
    print(f"parsed {len(files) - len(empty)} Bandai BVH files, {frames} frames, in {elapsed:.2f} s")
    assert len(files) - len(empty) == 174 + 1328  # dataset-1 (one file empty upstream) + dataset-2 ids 001-019
