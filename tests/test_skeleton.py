import pytest

from motionaug.schemas.skeleton import KIT, T2M, Skeleton, get_skeleton


def test_t2m_layout() -> None:
    assert T2M.n_joints == 22
    assert T2M.feature_dim == 263
    assert T2M.parents[0] == -1
    assert T2M.parents[15] == 12 and T2M.parents[20] == 18
    assert KIT.feature_dim == 251


def test_mirror_permutation_is_an_involution() -> None:
    perm = T2M.mirror_permutation
    assert [perm[p] for p in perm] == list(range(T2M.n_joints))
    assert T2M.joint_names[perm[1]] == "right_hip"


def test_bad_skeleton_is_rejected() -> None:
    with pytest.raises(ValueError, match="offsets"):
        Skeleton(
            name="bad",
            joint_names=["a", "b"],
            kinematic_chain=[[0, 1]],
            raw_offsets=[(0, 0, 0)],
            feet_left=(0, 1),
            feet_right=(0, 1),
            face_joints=(0, 1, 0, 1),
            leg_joints=(0, 1),
        )
    with pytest.raises(ValueError, match="unknown skeleton"):
        get_skeleton("nope")
