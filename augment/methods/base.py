"""The contract between a style-transfer method and the workflow that fans it out.

Every method declares the same steps on ``StyleTransferMethod``; the workflow asks, it never guesses: ``Params``
(validated before Ray starts); ``train`` (optional, ``trains = True``: once per run, the models every style shares,
reused while ``is_trained`` says a folder holds them); ``check_style`` (config time); ``prepare`` (once per style,
an artefact folder from the style's examples: a template around the method's ``prepare_style``, timed by the
workflow); ``load`` + ``StyleModel.transfer`` (a worker loads an artefact once and stylizes batches of clips).
Artefacts are plain files so the workflow can move them between machines.
"""

from __future__ import annotations

import json
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Protocol

from pydantic import BaseModel, ValidationError

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.corpus.rejects import Reject
from motionaug.augment.io import atomic_write_text
from motionaug.augment.outputs.checksums import TIMINGS_FILE
from motionaug.augment.outputs.shards import TransferOutput
from motionaug.schemas.errors import MotionDataError, first_error
from motionaug.schemas.styles import StyleSpec

ARTIFACT_JSON = "artifact.json"
ARTIFACT_WEIGHTS = "weights.safetensors"

Progress = Callable[[int, int, dict[str, float]], None]
"""``progress(step, total, metrics)``: called by long loops so callers can draw bars."""

TrainProgress = Callable[[str, int, int, dict[str, float]], None]
"""``progress(stage, step, total, metrics)``: the same for a training with several stages."""


@dataclass(frozen=True)
class Prepared:
    """What ``prepare_style`` made: the artefact folder and, optionally, timings of its parts (seconds)."""

    folder: Path
    timings: Mapping[str, Any] = field(default_factory=dict)


def write_timings(prepared: Prepared, seconds: float) -> None:
    """``TIMINGS_FILE`` in the artefact folder, outside its checksum: the step's seconds as its runner measured
    them, and the parts the method timed."""
    timings = {"prepare_s": seconds, **prepared.timings}
    atomic_write_text(prepared.folder / TIMINGS_FILE, json.dumps(timings, indent=1, sort_keys=True) + "\n")


@dataclass(frozen=True)
class CostRates:
    """A method's measured costs on the project VM (1 CPU per task, CPU torch), for ``motionaug run --dry-run``."""

    prepare_s: float | None = None  # one style's prepare task; None: not measured
    transfer_clips_per_s: float | None = None  # one transfer task
    train_s: float | None = None  # the once-per-run training, when the method trains
    artefact_bytes: int | None = None  # one style's published artefact


@dataclass(frozen=True)
class TrainingSpec:
    """What a run asks of a method's ``train``: the network size (``base_models.size``) and the seed. The method's
    own training settings are in its params (``method.params.train``)."""

    size: str
    seed: int


class StyleModel(Protocol):
    """A loaded style artefact; stays warm in a worker and serves many batches."""

    style: str

    def transfer(self, clips: Sequence[MotionClip], seed: int = 0) -> list[TransferOutput | Reject]:
        """Stylize a batch. A bad clip comes back as a ``Reject`` in its place; it never fails the batch."""
        ...


class StyleTransferMethod(ABC):
    """A way of learning styles and applying them to clips."""

    name: ClassVar[str]
    Params: ClassVar[type[BaseModel]]
    trains: ClassVar[bool] = False
    """Whether the method has a once-per-run ``train`` step."""
    cost_rates: ClassVar[CostRates] = CostRates()
    """Measured costs per task, the dry run's estimates (``CostRates``)."""
    smoke_params: ClassVar[dict[str, Any]] = {}
    """Params for a seconds-long run of every step (the contract test, ``motionaug demo --size tiny``)."""
    removed_params: ClassVar[Mapping[str, str]] = {}
    """Settings that left ``Params`` (dotted for nested ones, ``train.w_acc``) and what to do instead."""
    path_params: ClassVar[tuple[str, ...]] = ()
    """Params that name files (dotted): a relative one resolves against the config file's folder."""

    def __init__(self, params: Mapping[str, Any] | BaseModel | None = None) -> None:
        self.params = self.parse_params(params)

    @classmethod
    def parse_params(cls, raw: Mapping[str, Any] | BaseModel | None) -> BaseModel:
        """The validated params; a bad one is one line naming ``method.params.<field>``."""
        if isinstance(raw, cls.Params):
            return raw
        data = raw.model_dump() if isinstance(raw, BaseModel) else dict(raw or {})
        for dotted, what in cls.removed_params.items():
            *parents, leaf = dotted.split(".")
            level: Any = data
            for part in parents:
                level = level.get(part) if isinstance(level, Mapping) else None
            if isinstance(level, Mapping) and leaf in level:
                raise MotionDataError(f"config method.params.{dotted}", f"{cls.name}: removed; {what}")
        try:
            return cls.Params.model_validate(data)
        except ValidationError as err:
            where, message = first_error(err, "")
            raise MotionDataError(f"config method.params.{where}".rstrip("."), f"{cls.name}: {message}") from None

    def content_clips(self) -> int:
        """How many content clips of the plan's pool ``prepare`` is handed (0: none), as these params need them.

        The plan chooses them once per run, whatever the unit size; every style's ``prepare`` sees the same ones.
        """
        return 0

    # ---- once per run ---------------------------------------------------------------------------------

    def check_training(self, spec: TrainingSpec) -> None:
        """Config-time check of what ``train`` would be asked (before Ray starts); default: nothing to check."""

    def is_trained(self, folder: Path) -> bool:
        """Whether ``folder`` already holds this method's trained models (then they are reused as they are)."""
        return False

    def train(self, corpus: Path, out: Path, spec: TrainingSpec, progress: TrainProgress | None = None) -> Path:
        """Train the models every style shares on the labelled ``corpus`` into ``out``; returns the folder."""
        raise NotImplementedError(f"method {self.name!r} has no train step (trains = False)")

    # ---- once per style -------------------------------------------------------------------------------

    def check_style(self, style: StyleSpec, trained: Path | None, corpus: Path | None = None) -> None:
        """Config-time check of one style; ``trained``: the trained folder when it exists already; ``corpus``: the
        labelled corpus ``train`` learns from."""

    def prepare(
        self,
        style: StyleSpec,
        examples: Sequence[MotionClip],
        trained: Path | None,
        content: Sequence[MotionClip],
        out: Path,
        seed: int | None = None,
        progress: Progress | None = None,
    ) -> Prepared:
        """Learn ``style`` from its examples (and ``content``, the plan's pool); write the artefact under ``out``.

        A template: the checks every method shares, then ``prepare_style``. The artefact folder and the timings the
        method reports come back; whoever runs the step (the workflow's prepare stage) records them with the
        seconds it measured (``write_timings``).
        """
        if self.trains and trained is None:
            raise MotionDataError(f"{self.name} prepare", "needs the trained models (the train step's folder)")
        if not examples:
            raise MotionDataError(f"style {style.name!r}", "no example clips")
        return self.prepare_style(style, examples, trained, content, Path(out), seed, progress)

    def prepare_style(
        self,
        style: StyleSpec,
        examples: Sequence[MotionClip],
        trained: Path | None,
        content: Sequence[MotionClip],
        out: Path,
        seed: int | None,
        progress: Progress | None,
    ) -> Prepared:
        """``prepare``'s own work, its arguments checked. ``seed`` None: the method's params' own. The default
        records the style only, for methods that condition on it at transfer time."""
        out.mkdir(parents=True, exist_ok=True)
        record = {"method": self.name, "style": style.model_dump(mode="json"), "examples": [c.id for c in examples]}
        atomic_write_text(out / ARTIFACT_JSON, json.dumps(record, indent=1, sort_keys=True) + "\n")
        return Prepared(out)

    @abstractmethod
    def load(self, artifact: Path, trained: Path | None) -> StyleModel:
        """Load an artefact written by ``prepare`` (and the trained models it needs)."""
