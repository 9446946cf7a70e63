"""Retarget BVH motion onto the t2m (HumanML3D) joints by a joint map, and resample it in time.

Retargeting is position based: every target joint is a source joint or an affine blend of source joints (weights sum
to 1), in metres with Y up. HumanML3D's feature extraction re-derives rotations, facing and floor height from these
positions, so no bone rotations need transferring. A joint map (JSON or YAML: ``version``, ``name``, ``skeleton``,
``scale``, ``up_axis``, ``handedness``, ``joints``; docs/retargeting.md has an example) names every target joint once.
After conversion a character facing +Z must have its left side on +X (t2m's left hip is joint 1 and HumanML3D's
facing rule is ``forward = up x (right - left)``): a map with left/right swapped, or a left-handed source marked
"right", yields mirrored motion.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Literal

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from motionaug.augment.motion.bvh import BvhMotion, read_bvh
from motionaug.schemas.errors import MotionDataError, first_error
from motionaug.schemas.skeleton import get_skeleton

UpAxis = Literal["+x", "-x", "+y", "-y", "+z", "-z"]

# Proper rotations (det +1) taking each source up axis onto +Y, so handedness is kept.
_UP_TO_Y: dict[str, np.ndarray] = {
    "+y": np.eye(3),
    "-y": np.diag([1.0, -1.0, -1.0]),
    "+z": np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]),
    "-z": np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]),
    "+x": np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]),
    "-x": np.array([[0.0, 1, 0], [-1, 0, 0], [0, 0, 1]]),
}


class JointMap(BaseModel):
    """How to build each target joint from a source skeleton's joints, and the unit/axis fix-up."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    version: Literal[1] = 1
    name: str
    skeleton: str = "t2m"
    scale: float = Field(gt=0, description="Source units to metres.")
    up_axis: UpAxis = "+y"
    handedness: Literal["right", "left"] = "right"
    joints: dict[str, str | dict[str, float]]

    @field_validator("joints")
    @classmethod
    def _check_blends(cls, joints: dict[str, str | dict[str, float]]) -> dict[str, str | dict[str, float]]:
        for target, spec in joints.items():
            if isinstance(spec, str):
                if not spec:
                    raise ValueError(f"{target}: empty source joint name")
                continue
            if not spec or not all(math.isfinite(w) for w in spec.values()):
                raise ValueError(f"{target}: a blend needs source joints with finite weights")
            if abs(sum(spec.values()) - 1.0) > 1e-6:
                raise ValueError(f"{target}: blend weights sum to {sum(spec.values()):g}, not 1")
        return joints

    @model_validator(mode="after")
    def _check_targets(self) -> JointMap:
        names = get_skeleton(self.skeleton).joint_names
        missing = [n for n in names if n not in self.joints]
        unknown = [n for n in self.joints if n not in names]
        if missing or unknown:
            raise ValueError(f"joint map {self.name!r} for {self.skeleton}: missing {missing}, unknown {unknown}")
        return self

    def blend(self, target: str) -> dict[str, float]:
        """Source joint -> weight for one target joint."""
        spec = self.joints[target]
        return {spec: 1.0} if isinstance(spec, str) else dict(spec)

    def source_joints(self) -> set[str]:
        return {src for target in self.joints for src in self.blend(target)}

    def axes(self) -> np.ndarray:
        """(3, 3) matrix taking scaled source coordinates to right-handed Y-up coordinates."""
        flip = np.diag([-1.0, 1.0, 1.0]) if self.handedness == "left" else np.eye(3)
        return flip @ _UP_TO_Y[self.up_axis]

    @classmethod
    def from_file(cls, path: str | os.PathLike[str]) -> JointMap:
        """Load a map from ``.json``, ``.yaml`` or ``.yml``; problems raise ``MotionDataError``."""
        source = str(path)
        try:
            text = Path(path).read_text(encoding="utf-8")
            data = yaml.safe_load(text) if Path(path).suffix.lower() in {".yaml", ".yml"} else json.loads(text)
        except (OSError, ValueError, yaml.YAMLError) as err:
            raise MotionDataError(source, f"cannot read joint map: {str(err).splitlines()[0]}") from None
        if not isinstance(data, dict):
            raise MotionDataError(source, "joint map must be a mapping")
        try:
            return cls.model_validate(data)
        except ValidationError as err:
            where, message = first_error(err, "map")
            raise MotionDataError(source, f"bad joint map: {where}: {message}") from None


def _sides(side: str, letter: str) -> dict[str, str | dict[str, float]]:
    return {
        f"{side}_collar": f"Shoulder_{letter}",
        f"{side}_shoulder": f"UpperArm_{letter}",
        f"{side}_elbow": f"LowerArm_{letter}",
        f"{side}_wrist": f"Hand_{letter}",
        f"{side}_hip": f"UpperLeg_{letter}",
        f"{side}_knee": f"LowerLeg_{letter}",
        f"{side}_ankle": f"Foot_{letter}",
        f"{side}_foot": f"Toes_{letter}",
    }


# Bandai Namco Research datasets 1 and 2: cm, Y up, right-handed, *_L on the performer's left
# (checked: facing +Z by the feet, *_L joints lie on +X). t2m's spine1/2/3 sit at about 22%, 48%
# and 59% of the pelvis->neck height; Bandai's Spine and Chest at 38% and 60%, so spine1 and
# spine2 are blends along the Hips->Spine and Spine->Chest bones and spine3 is Chest, which also
# keeps neck and collars rigid on spine3 as in t2m.
BANDAI_TO_T2M = JointMap(
    name="bandai",
    scale=0.01,
    joints={
        "pelvis": "Hips",
        "spine1": {"Hips": 0.4, "Spine": 0.6},
        "spine2": {"Spine": 0.5, "Chest": 0.5},
        "spine3": "Chest",
        "neck": "Neck",
        "head": "Head",
        **_sides("left", "L"),
        **_sides("right", "R"),
    },
)

BUILTIN_MAPS: tuple[JointMap, ...] = (BANDAI_TO_T2M,)


def retarget_positions(motion: BvhMotion, joint_map: JointMap) -> np.ndarray:
    """(F, J, 3) float64 target joint positions in metres, Y up, right-handed."""
    missing = sorted(joint_map.source_joints() - set(motion.names))
    if missing:
        reason = f"joint map {joint_map.name!r} needs joints absent from the file: {missing}"
        raise MotionDataError(motion.source, reason)
    source = motion.global_positions()
    index = {name: j for j, name in enumerate(motion.names)}
    targets = get_skeleton(joint_map.skeleton).joint_names
    weights = np.zeros((len(targets), motion.n_joints))
    for t, target in enumerate(targets):
        for src, w in joint_map.blend(target).items():
            weights[t, index[src]] += w
    blended = np.einsum("tj,fja->fta", weights, source)
    return joint_map.scale * blended @ joint_map.axes().T


def resample(positions: np.ndarray, src_fps: float, dst_fps: float = 20.0) -> np.ndarray:
    """Linearly interpolate (F, ...) frames from ``src_fps`` to ``dst_fps``, keeping the start time.

    Output has ``floor((F - 1) * dst / src) + 1`` frames, so it never extrapolates past the end.
    """
    positions = np.asarray(positions)
    if not (src_fps > 0 and dst_fps > 0):
        raise ValueError(f"frame rates must be positive, got {src_fps} -> {dst_fps}")
    n_src = positions.shape[0]
    if n_src < 1:
        raise ValueError("cannot resample an empty clip")
    n_dst = math.floor((n_src - 1) * dst_fps / src_fps + 1e-9) + 1
    at = np.minimum(np.arange(n_dst) * (src_fps / dst_fps), n_src - 1)
    lo = np.floor(at).astype(int)
    hi = np.minimum(lo + 1, n_src - 1)
    frac = (at - lo).reshape((-1,) + (1,) * (positions.ndim - 1))
    return positions[lo] * (1 - frac) + positions[hi] * frac


def nominal_fps(frame_time: float) -> float:
    """1 / frame_time, snapped to a whole number when files round it (0.0333333 -> 30)."""
    fps = 1.0 / frame_time
    nearest = round(fps)
    return float(nearest) if nearest > 0 and abs(fps - nearest) < 1e-4 * fps else fps


def detect_joint_map(motion: BvhMotion) -> JointMap:
    """The built-in map whose source joints all exist in ``motion``."""
    names = set(motion.names)
    for joint_map in BUILTIN_MAPS:
        if joint_map.source_joints() <= names:
            return joint_map
    reason = f"no joint map for skeleton with joints {motion.names}; pass one (docs/retargeting.md)"
    raise MotionDataError(motion.source, reason)


def load_bvh_as_t2m_joints(
    path: str | os.PathLike[str], joint_map: JointMap | str | os.PathLike[str] | None = None, fps: float = 20.0
) -> tuple[np.ndarray, float]:
    """Read a BVH and return (joints (T, J, 3) in metres at ``fps``, the file's frame rate).

    ``joint_map`` may be a ``JointMap``, a path to a map file, or None to detect a built-in map.
    """
    motion = read_bvh(path)
    if joint_map is None:
        joint_map = detect_joint_map(motion)
    elif not isinstance(joint_map, JointMap):
        joint_map = JointMap.from_file(joint_map)
    source_fps = nominal_fps(motion.frame_time)
    return resample(retarget_positions(motion, joint_map), source_fps, fps), source_fps


def labels_from_bandai(path: str | os.PathLike[str]) -> tuple[str, str]:
    """(content, style) of a Bandai clip: its JSON label indices + ``cfg/`` names, else its file name.

    The label files list ``dataset-N_<label>`` one a line, indexed from 0 by the JSON.
    """
    path = Path(path)
    labels = _labels_from_json(path)
    if labels is not None:
        return labels
    parts = path.stem.split("_")
    if len(parts) == 4 and parts[0].startswith("dataset-") and parts[1] and parts[2]:
        return parts[1], parts[2]
    raise MotionDataError(str(path), "no label JSON and the name is not dataset-N_{content}_{style}_{id}")


def _labels_from_json(path: Path) -> tuple[str, str] | None:
    label_json = path.with_suffix(".json")
    cfg = path.parent.parent / "cfg"
    if not label_json.is_file() or not cfg.is_dir():
        return None
    try:
        indices = json.loads(label_json.read_text(encoding="utf-8"))
        content = _label_line(cfg / "content_label.txt", indices["content"])
        style = _label_line(cfg / "style_label.txt", indices["style"])
    except (OSError, ValueError, KeyError, TypeError, IndexError) as err:
        raise MotionDataError(str(label_json), f"unusable Bandai labels ({type(err).__name__}: {err})") from None
    return content, style


def _label_line(label_file: Path, index: int) -> str:
    if not isinstance(index, int) or index < 0:
        raise ValueError(f"label index {index!r} in {label_file.name}")
    lines = [ln.strip() for ln in label_file.read_text(encoding="utf-8").splitlines() if ln.strip()]
    label = lines[index]
    prefix, sep, rest = label.partition("_")
    return rest if sep and prefix.startswith("dataset-") else label
