"""Where a clip goes over the ground: whether it travels at all, and whether forwards or backwards.

Output shaping reads these to match a clip with the style example that moves as it does (``travels``) and to play
a clip that travels against the example's direction backwards through a time-lagged map (``opposed``).
"""

from __future__ import annotations

import numpy as np

from motionaug.augment.motion.features import feature_slices
from motionaug.schemas.skeleton import T2M

TRAVEL_SPEED = 0.1  # m/s net: under a slow style's walk (0.16 and up), over squatting, kicking or swaying on the spot
AXIAL = 0.5  # the least share of the mean velocity along the facing axis for a clip to go forwards or backwards


def _ground_velocity(motion: np.ndarray) -> np.ndarray:
    """(T, 2) root velocity per frame in the facing frame: sideways, forwards (HumanML3D's ``root_lin_vel``)."""
    return np.asarray(motion)[:, feature_slices(T2M)["root_lin_vel"]]


def travels(motion: np.ndarray, fps: float) -> bool:
    """Whether a clip goes somewhere (a walk, a run) rather than staying in place (a wave): its net ground speed,
    the magnitude of its mean velocity in the facing frame, against ``TRAVEL_SPEED``. Net, not the mean speed: a
    squat, a kick or a dance on the spot moves the root back and forth as fast as an old person's walk moves it
    forwards, but goes nowhere."""
    return bool(np.linalg.norm(_ground_velocity(motion).mean(axis=0)) * fps > TRAVEL_SPEED)


def heading(motion: np.ndarray) -> float:
    """The mean velocity's forward component over the mean ground speed: 1 straight forwards, -1 straight backwards,
    near 0 for a sidestep or a clip on the spot."""
    velocity = _ground_velocity(motion)
    return float(velocity[:, 1].mean() / (np.linalg.norm(velocity, axis=1).mean() + 1e-6))


def opposed(clip: np.ndarray, example: np.ndarray, fps: float) -> bool:
    """Whether both travel along their facing axes (``AXIAL``), one forwards and the other backwards."""
    if not (travels(clip, fps) and travels(example, fps)):
        return False
    a, b = heading(clip), heading(example)
    return min(abs(a), abs(b)) > AXIAL and a * b < 0
