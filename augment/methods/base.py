"""The contract between a style-transfer method and the workflow that fans it out.

A method learns a style once (``prepare`` -> an artefact folder: ``weights.safetensors`` +
``artifact.json``), then any worker loads that artefact once (``load``) and stylizes batches of clips
(``StyleModel.transfer``). Artefacts are plain files so the workflow can move them between machines.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Protocol

import numpy as np

from augment.clip import MotionClip
from augment.corpus.rejects import Reject
from schemas.captions import Caption
from schemas.styles import StyleSpec

ARTIFACT_JSON = "artifact.json"
ARTIFACT_WEIGHTS = "weights.safetensors"

Progress = Callable[[int, int, dict[str, float]], None]
"""``progress(step, total, metrics)``: called by long loops so callers can draw bars."""


@dataclass
class TransferOutput:
    """One stylized clip. ``motion`` is (T, D) float32 un-normalised features like the input's."""

    source_id: str
    style: str
    motion: np.ndarray
    captions: list[Caption]
    scores: dict[str, float] = field(default_factory=dict)


class StyleModel(Protocol):
    """A loaded style artefact; stays warm in a worker and serves many batches."""

    style: str

    def transfer(self, clips: Sequence[MotionClip], seed: int = 0) -> list[TransferOutput | Reject]:
        """Stylize a batch. A bad clip comes back as a ``Reject`` in its place; it never fails the batch."""
        ...


class StyleTransferMethod(ABC):
    """A way of learning a style from examples and applying it to clips."""

    name: ClassVar[str]

    @abstractmethod
    def prepare(
        self,
        style: StyleSpec,
        examples: Sequence[MotionClip],
        base_dir: Path,
        corpus: Sequence[MotionClip],
        out_dir: Path,
        seed: int | None = None,
        progress: Progress | None = None,
    ) -> Path:
        """Learn ``style`` from its example clips; write the artefact under ``out_dir`` and return it.

        ``base_dir`` holds the pre-trained base models; ``corpus`` is the content the style should
        generalise to (the semantic loss draws batches from it). ``seed``: None uses the method's own params.
        """

    @abstractmethod
    def load(self, artifact_dir: Path, base_dir: Path, **options: Any) -> StyleModel:
        """Load an artefact written by ``prepare`` (and the base models it needs)."""
