"""Data-layer figures: feature recovery and round-trip errors on real data, and every Bandai BVH parsed.

.venv/bin/python bench/bench_representation.py [--shared ../shared/data]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from motionaug.augment.motion.bvh import read_bvh
from motionaug.augment.motion.features import extract_features_and_joints, recover_from_ric, recover_from_rot
from motionaug.augment.synth.animator import ClipSpec, render
from motionaug.schemas.errors import MotionDataError

REPO = Path(__file__).resolve().parents[1]


def round_trip_error(joints: np.ndarray) -> tuple[float, float]:
    """(max |recover_from_ric - canonical joints|, max |recover_from_rot - recover_from_ric|) in metres."""
    ex = extract_features_and_joints(joints)
    feats = torch.from_numpy(ex.features).double()
    ric = recover_from_ric(feats, joints.shape[1]).numpy()
    rot = recover_from_rot(feats, joints.shape[1]).numpy()
    return float(np.abs(ric - ex.joints[:-1]).max()), float(np.abs(rot - ric).max())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--shared", type=Path, default=REPO.parent / "shared" / "data")
    args = parser.parse_args()
    torch.set_num_threads(1)
    sample = args.shared / "humanml3d_sample"
    vecs = np.load(sample / "new_joint_vecs" / "012314.npy")
    joints = np.load(sample / "new_joints" / "012314.npy")
    err = np.abs(recover_from_ric(torch.from_numpy(vecs), 22).numpy() - joints).max()
    print(f"recover_from_ric(new_joint_vecs/012314) vs new_joints/012314: max abs error {err:.2e} m")
    ric, rot = round_trip_error(joints.astype(np.float64))
    print(
        f"round trip joints -> features -> joints, real clip 012314: {ric:.2e} m (recover_from_rot vs ric {rot:.2e} m)"
    )
    worst = max(
        round_trip_error(render(ClipSpec(content=c, style=s, duration=4.0)).joints.astype(np.float64))[0]
        for c in ("walk", "walk_curve", "jump", "kick", "turn")
        for s in ("neutral", "old", "strutting")
    )
    print(f"round trip, 15 synthetic clips (walk, curve, jump, kick, turn x 3 styles): worst {worst:.2e} m")
    files = sorted((args.shared / "bandai").rglob("*.bvh"))
    start, parsed, frames, mismatched, failed = time.perf_counter(), 0, 0, 0, []
    for path in files:
        try:
            motion = read_bvh(path)
        except MotionDataError as err:
            failed.append(str(err))
            continue
        header = int(
            next(line for line in path.read_text().splitlines() if line.strip().startswith("Frames:")).split()[1]
        )
        mismatched += motion.n_frames != header
        parsed, frames = parsed + 1, frames + motion.n_frames
    print(
        f"BVH: {parsed} of {len(files)} files parsed ({frames} frames, {mismatched} frame counts off the header) "
        f"in {time.perf_counter() - start:.1f} s; refused: {failed}"
    )


if __name__ == "__main__":
    main()
