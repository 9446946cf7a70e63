"""A run's stylized clips as BVH files on the t2m skeleton, for animation tools (Blender, MotionBuilder).

Features -> joint positions (``recover_from_ric``) -> ``augment.motion.bvh.joints_to_bvh``, one ``<output_id>.bvh``
per clip; output ids come from shard data, so each is checked to be a plain file name first. Rotations alone
reproduce only rigid motion, and generated clips are not rigid (positions from ``recover_from_ric``, bone lengths
that drift), so when the rigid fit misses a joint by more than ``tolerance`` the file also carries per-joint position
channels (the MotionBuilder layout) with the clip's own bone vectors: then every joint lands where the clip has it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from motionaug.augment.corpus.humanml3d import check_id
from motionaug.augment.motion.bvh import joints_to_bvh, read_bvh, write_bvh
from motionaug.augment.motion.features import features_to_joints
from motionaug.augment.outputs.run_dir import RunDir
from motionaug.augment.outputs.shards import iter_shard_rows, row_motion
from motionaug.augment.outputs.verify import verified_shards
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import T2M

_COLUMNS = ["output_id", "style", "motion", "n_frames", "n_feats", "fps"]


EXACT_TOLERANCE_M = 1e-4


@dataclass
class BvhExportSummary:
    out: Path
    files: int
    max_error_m: float  # largest joint-position error of a written skeleton against its joints
    with_positions: int = 0  # files that needed per-joint position channels (non-rigid clips)


def write_clip_bvh(
    path: Path, joints: np.ndarray, fps: float, tolerance: float = EXACT_TOLERANCE_M
) -> tuple[float, bool]:
    """One clip (T, 22, 3) as BVH; returns (max joint error in metres, whether position channels were needed)."""
    error = joints_to_bvh(path, joints, fps)
    if error <= tolerance:
        return error, False
    rigid = read_bvh(path)
    to_t2m = [T2M.joint_names.index(name) for name in rigid.names]  # file joint -> t2m joint
    positions = np.asarray(joints, dtype=np.float64)[:, to_t2m]  # (T, J, 3) in file order
    rotations, _ = rigid.global_transforms()
    translations = positions.copy()
    for j, parent in enumerate(rigid.parents):
        if parent >= 0:  # the bone vector in the parent's frame: R_parent^T (p_j - p_parent)
            bone = positions[:, j] - positions[:, parent]
            translations[:, j] = np.einsum("fba,fb->fa", rotations[:, parent], bone)
    write_bvh(
        path,
        rigid.names,
        rigid.parents,
        rigid.offsets,
        rigid.local_quaternions(),
        positions[:, 0],
        fps,
        end_sites=rigid.end_sites,
        translations=translations,
    )
    return float(np.abs(read_bvh(path).global_positions() - positions).max()), True


def export_bvh(run_dir: str | Path, out: str | Path, style: str | None = None) -> BvhExportSummary:
    """Write every stylized clip of a complete run (or of one ``style``) as ``out/<output_id>.bvh``."""
    run_dir, out = Path(run_dir), Path(out)
    config = RunDir(run_dir).manifest().config
    styles = [s["name"] for s in config.get("styles", [])]
    if style is not None and style not in styles:
        raise MotionDataError("--style", f"run has no style {style!r}; its styles are {styles}")
    if out.exists() and not out.is_dir():
        raise MotionDataError(str(out), "exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    files, worst, with_positions = 0, 0.0, 0
    for row in iter_shard_rows(run_dir, columns=_COLUMNS, files=verified_shards(RunDir(run_dir), style=style)):
        if style is not None and row["style"] != style:
            continue
        name = check_id(row["output_id"], f"output id in {run_dir}")
        joints = features_to_joints(row_motion(row), T2M, source=f"stylized clip {name}")
        error, exact = write_clip_bvh(out / f"{name}.bvh", joints, float(np.float32(row["fps"])))
        worst, files, with_positions = max(worst, error), files + 1, with_positions + exact
    if files == 0:
        raise MotionDataError(str(run_dir), "no stylized clips to export" + (f" for style {style!r}" if style else ""))
    return BvhExportSummary(out=out, files=files, max_error_m=worst, with_positions=with_positions)
