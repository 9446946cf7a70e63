"""The coordination map on the skeleton's bones instead of its joint positions: does a map whose coordinates are the
bones lose less of the style to ``bone_lengths`` afterwards? (Without ``unit`` it is the product's ``coordination``
with ``basis: bones``, bit-identical; no config names it: lab/NOTES.md 0.)

- output shaper ``coordination_bones`` (``lag``, ``taps``, ``floor`` as the product's ``coordination``; ``unit``): the
  product's whitening-colouring map, delay-embedded and played backwards where the content travels against the
  example, taken over the root height and the 21 bone vectors (child joint less parent joint) instead of the root
  height and the 21 root-relative joint positions; the joints are rebuilt down the kinematic chains from the mapped
  bones. With ``unit`` the bones are scaled to unit length before the covariances and the map, and the mapped
  directions are given back the output's own per-frame lengths: the map then moves directions only.

Why: on Bandai-2 the map alone reads more of style judge 2 than the chain keeps once ``bone_lengths`` has put the
content's bones back (lab/NOTES 0, "Where Bandai-2's judge 2 goes along the chain"). Bones are a linear, invertible
change of coordinates of the positions, but the symmetric square roots of whitening-colouring are not invariant to such
a change, so the two maps differ in the rotation part of the map, the part judge 2 reads; a map of directions cannot
stretch a bone at all. Control: ``--row shapers`` with the product's ``coordination`` (``dx9-chain``).
"""

from __future__ import annotations

import numpy as np

from motionaug.augment.methods.hooks import output_shapers
from motionaug.augment.methods.shapers import BONES, Coordination, bone_channels, with_bone_channels


def bones_of(features: np.ndarray, unit: bool) -> tuple[np.ndarray, np.ndarray]:
    """The product's ``bone_channels`` (each bone scaled to unit length with ``unit``), and (T, bones) lengths."""
    channels = bone_channels(features)
    bones = channels[:, 1:].reshape(len(features), len(BONES), 3)
    length = np.linalg.norm(bones, axis=-1)
    if unit:
        bones = bones / np.maximum(length[..., None], 1e-9)
    return np.concatenate([channels[:, :1], bones.reshape(len(features), -1)], axis=1), length


def with_bones(features: np.ndarray, channels: np.ndarray, length: np.ndarray | None) -> np.ndarray:
    """The product's ``with_bone_channels``; with ``length`` (T, bones), each bone scaled to it first."""
    if length is not None:
        bones = channels[:, 1:].reshape(len(features), len(BONES), 3)
        bones = bones / np.maximum(np.linalg.norm(bones, axis=-1, keepdims=True), 1e-9) * length[..., None]
        channels = np.concatenate([channels[:, :1], bones.reshape(len(features), -1)], axis=1)
    return with_bone_channels(features, channels)


@output_shapers.register("coordination_bones")
class CoordinationBones(Coordination):
    """The product's coordination map over the bones, or their directions with ``unit`` (module doc)."""

    def __init__(self, lag: int = 3, taps: int = 6, floor: float = 1e-3, unit: bool = False) -> None:
        super().__init__(shrink=0.0, floor=floor, lag=lag, taps=taps, basis="bones")
        self.unit = bool(unit)

    def _coordinates(self, motion: np.ndarray) -> np.ndarray:
        return bones_of(motion, self.unit)[0]

    def _rebuild(self, output: np.ndarray, mapped: np.ndarray) -> np.ndarray:
        return with_bones(output, mapped, bones_of(output, True)[1] if self.unit else None)
