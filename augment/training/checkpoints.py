"""Training checkpoints a stopped pretraining resumes from, bit for bit.

Per stage, one folder per saved step holds the weights (safetensors, never unpickled) and ``state.pt`` (optimizer
and RNG states, read back only with ``torch.load(weights_only=True)``, which refuses anything but tensors and plain
containers); ``<stage>/latest.json`` (``StageCheckpoint``) names the current step folder and is replaced atomically
after that folder is complete, so a run killed mid-write resumes from the previous checkpoint.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from pydantic import BaseModel, ConfigDict
from torch import nn

from motionaug.augment.io import atomic_path, atomic_write_text
from motionaug.augment.training.base_models import load_module, save_module
from motionaug.schemas.errors import MotionDataError

LATEST = "latest.json"
STATE_FILE = "state.pt"


class StageCheckpoint(BaseModel):
    """What ``latest.json`` records: the stage, how far it got, and under which config."""

    model_config = ConfigDict(extra="forbid")

    version: int = 1
    stage: str
    step: int
    total: int
    done: bool = False
    config_hash: str
    folder: str  # step folder name, relative to the stage folder
    metrics: dict[str, float] = {}


@dataclass
class Resumed:
    """A loaded checkpoint: its record and the tensors of ``state.pt`` (optimizer, RNG states, extras)."""

    record: StageCheckpoint
    state: dict[str, Any]


def stage_dir(root: Path, stage: str) -> Path:
    return Path(root) / stage


def save_checkpoint(
    root: Path,
    record: StageCheckpoint,
    modules: dict[str, nn.Module],
    state: dict[str, Any],
) -> None:
    """Write weights and state into a fresh step folder, point ``latest.json`` at it, drop older folders."""
    folder = stage_dir(root, record.stage) / record.folder
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    for name, module in modules.items():
        save_module(module, folder / f"{name}.safetensors")
    with atomic_path(folder / STATE_FILE) as tmp:
        torch.save(state, tmp)
    atomic_write_text(stage_dir(root, record.stage) / LATEST, record.model_dump_json(indent=2))
    for old in stage_dir(root, record.stage).glob("step_*"):
        if old.name != record.folder:
            shutil.rmtree(old, ignore_errors=True)


def step_folder(step: int) -> str:
    return f"step_{step:07d}"


def read_record(root: Path, stage: str) -> StageCheckpoint | None:
    """The stage's latest record, or None when it never checkpointed."""
    path = stage_dir(root, stage) / LATEST
    if not path.is_file():
        return None
    try:
        return StageCheckpoint.model_validate_json(path.read_text(encoding="utf-8"))
    except ValueError as err:
        raise MotionDataError(str(path), f"unreadable checkpoint record ({str(err).splitlines()[0]})") from None


def load_checkpoint(root: Path, stage: str, config_hash: str, modules: dict[str, nn.Module]) -> Resumed | None:
    """Load the stage's latest weights into ``modules`` and return its state; None when there is nothing to resume.

    A checkpoint written under another config is an error, not silently reused or overwritten.
    """
    record = read_record(root, stage)
    if record is None:
        return None
    if record.config_hash != config_hash:
        reason = f"checkpoint was made with config {record.config_hash}, this run has {config_hash}; use a fresh folder"
        raise MotionDataError(str(stage_dir(root, stage)), reason)
    folder = stage_dir(root, stage) / record.folder
    for name, module in modules.items():
        load_module(module, folder / f"{name}.safetensors")
    state_path = folder / STATE_FILE
    if not state_path.is_file():
        raise MotionDataError(str(state_path), "checkpoint state is missing")
    try:
        state = torch.load(state_path, weights_only=True, map_location="cpu")
    except Exception as err:  # torch raises several types for corrupt or unsafe files
        raise MotionDataError(str(state_path), f"unreadable checkpoint state ({err})") from None
    return Resumed(record, state)
