"""Skeleton descriptions: topology, rest directions and the joints the feature extraction needs.

A skeleton is data, not code: the HumanML3D feature extraction is generic over it, so KIT or a
user's own rig work by writing one of these. Numbers follow HumanML3D's ``paramUtil.py``.
"""

from __future__ import annotations

from functools import cached_property

from pydantic import BaseModel, ConfigDict, Field, model_validator


class Skeleton(BaseModel):
    """Joint tree plus the semantic joints HumanML3D's extraction relies on.

    ``raw_offsets`` are unit directions of each bone in the rest pose (the reference's
    ``*_raw_offsets``); bone lengths come from a target clip at extraction time.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    version: int = 1
    name: str
    joint_names: list[str]
    kinematic_chain: list[list[int]] = Field(description="Chains from a joint to an end effector.")
    raw_offsets: list[tuple[float, float, float]]
    fps: float = 20.0
    feet_left: tuple[int, int] = Field(description="(ankle, toe) joints of the left foot.")
    feet_right: tuple[int, int] = Field(description="(ankle, toe) joints of the right foot.")
    face_joints: tuple[int, int, int, int] = Field(
        description="(r_hip, l_hip, r_shoulder, l_shoulder): defines the facing direction."
    )
    leg_joints: tuple[int, int] = Field(
        description="(knee, ankle) of one leg; their offsets scale the root height when retargeting."
    )
    mirror_pairs: list[tuple[int, int]] = Field(
        default_factory=list, description="Left/right joint pairs swapped when mirroring."
    )

    @model_validator(mode="after")
    def _check(self) -> Skeleton:
        n = len(self.joint_names)
        if len(self.raw_offsets) != n:
            raise ValueError(f"skeleton {self.name}: {len(self.raw_offsets)} offsets for {n} joints")
        seen = {0}
        for chain in self.kinematic_chain:
            if chain[0] not in seen:
                raise ValueError(f"skeleton {self.name}: chain {chain} starts at an unreached joint")
            seen.update(chain)
        if seen != set(range(n)):
            raise ValueError(f"skeleton {self.name}: chains miss joints {sorted(set(range(n)) - seen)}")
        return self

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @cached_property
    def parents(self) -> list[int]:
        """Parent index per joint (-1 for the root), derived from the chains."""
        parents = [-1] * self.n_joints
        for chain in self.kinematic_chain:
            for parent, child in zip(chain[:-1], chain[1:]):
                parents[child] = parent
        return parents

    @property
    def feature_dim(self) -> int:
        """Width of the HumanML3D feature vector: 4 + 3(J-1) + 6(J-1) + 3J + 4."""
        j = self.n_joints
        return 4 + 3 * (j - 1) + 6 * (j - 1) + 3 * j + 4

    @cached_property
    def mirror_permutation(self) -> list[int]:
        perm = list(range(self.n_joints))
        for a, b in self.mirror_pairs:
            perm[a], perm[b] = b, a
        return perm


T2M_JOINT_NAMES = [
    "pelvis",
    "left_hip",
    "right_hip",
    "spine1",
    "left_knee",
    "right_knee",
    "spine2",
    "left_ankle",
    "right_ankle",
    "spine3",
    "left_foot",
    "right_foot",
    "neck",
    "left_collar",
    "right_collar",
    "head",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
]

T2M = Skeleton(
    name="t2m",
    joint_names=T2M_JOINT_NAMES,
    kinematic_chain=[
        [0, 2, 5, 8, 11],
        [0, 1, 4, 7, 10],
        [0, 3, 6, 9, 12, 15],
        [9, 14, 17, 19, 21],
        [9, 13, 16, 18, 20],
    ],
    raw_offsets=[
        (0, 0, 0),
        (1, 0, 0),
        (-1, 0, 0),
        (0, 1, 0),
        (0, -1, 0),
        (0, -1, 0),
        (0, 1, 0),
        (0, -1, 0),
        (0, -1, 0),
        (0, 1, 0),
        (0, 0, 1),
        (0, 0, 1),
        (0, 1, 0),
        (1, 0, 0),
        (-1, 0, 0),
        (0, 0, 1),
        (0, -1, 0),
        (0, -1, 0),
        (0, -1, 0),
        (0, -1, 0),
        (0, -1, 0),
        (0, -1, 0),
    ],
    fps=20.0,
    feet_left=(7, 10),
    feet_right=(8, 11),
    face_joints=(2, 1, 17, 16),
    leg_joints=(5, 8),
    mirror_pairs=[(1, 2), (4, 5), (7, 8), (10, 11), (13, 14), (16, 17), (18, 19), (20, 21)],
)

KIT_JOINT_NAMES = [
    "root",
    "torso",
    "chest",
    "neck",
    "head",
    "r_shoulder",
    "r_elbow",
    "r_wrist",
    "l_shoulder",
    "l_elbow",
    "l_wrist",
    "r_hip",
    "r_knee",
    "r_ankle",
    "r_heel",
    "r_toe",
    "l_hip",
    "l_knee",
    "l_ankle",
    "l_heel",
    "l_toe",
]

KIT = Skeleton(
    name="kit",
    joint_names=KIT_JOINT_NAMES,
    kinematic_chain=[[0, 11, 12, 13, 14, 15], [0, 16, 17, 18, 19, 20], [0, 1, 2, 3, 4], [3, 5, 6, 7], [3, 8, 9, 10]],
    raw_offsets=[
        (0, 0, 0),
        (0, 1, 0),
        (0, 1, 0),
        (0, 1, 0),
        (0, 1, 0),
        (1, 0, 0),
        (0, -1, 0),
        (0, -1, 0),
        (-1, 0, 0),
        (0, -1, 0),
        (0, -1, 0),
        (1, 0, 0),
        (0, -1, 0),
        (0, -1, 0),
        (0, 0, 1),
        (0, 0, 1),
        (-1, 0, 0),
        (0, -1, 0),
        (0, -1, 0),
        (0, 0, 1),
        (0, 0, 1),
    ],
    fps=12.5,
    feet_left=(19, 20),
    feet_right=(14, 15),
    face_joints=(11, 16, 5, 8),
    leg_joints=(17, 18),
    mirror_pairs=[(5, 8), (6, 9), (7, 10), (11, 16), (12, 17), (13, 18), (14, 19), (15, 20)],
)

BUILTIN_SKELETONS: dict[str, Skeleton] = {"t2m": T2M, "kit": KIT}


def get_skeleton(name: str) -> Skeleton:
    try:
        return BUILTIN_SKELETONS[name]
    except KeyError:
        raise ValueError(f"unknown skeleton {name!r}; built in: {sorted(BUILTIN_SKELETONS)}") from None
