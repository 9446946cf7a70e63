"""The in-memory unit every reader yields and every writer takes."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from motionaug.schemas.captions import Caption


@dataclass
class MotionClip:
    """One motion with its captions. ``motion`` is (T, D) float32 HumanML3D features."""

    id: str
    motion: np.ndarray
    captions: list[Caption]
    fps: float = 20.0
    content: str | None = None
    style: str | None = None
    source: str = ""
    meta: dict[str, str] = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return int(self.motion.shape[0])
