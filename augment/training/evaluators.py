"""The evaluation classifiers (content, style): training and inference helpers, and their artefact.

The evaluators are an artefact of their own and score every method: ``motionaug pretrain`` writes them to ``<base
models>/evaluators/`` (``evaluators.json`` beside the two classifiers' weights; ``--evaluators-only`` for methods
that need no prior), and ``motionaug evaluate`` and the benchmarks read them there. No method trains against them.
Data is one tuple ``(joints (N, T, J, 3), mask (N, T), labels (N,))``, shuffled into mini-batches here, or any
iterable of such batches re-iterated every epoch. Data may stay on CPU: each batch moves to the model's device and
shuffling draws from a CPU generator, so a seed picks the same batches on every device.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from pydantic import BaseModel, ConfigDict, Field

from motionaug.augment.io import atomic_write_text, read_json_model
from motionaug.augment.metrics import recognition_accuracy
from motionaug.augment.training.base_models import CONTENT_CLASSIFIER, STYLE_CLASSIFIER, config_dict, save_module
from motionaug.models.evaluators import MotionClassifier
from motionaug.schemas.errors import MotionDataError

Batch = tuple[torch.Tensor, torch.Tensor, torch.Tensor]


def _check_tensors(data: Batch) -> Batch:
    joints, mask, labels = data
    if not (joints.shape[0] == mask.shape[0] == labels.shape[0]):
        raise MotionDataError(
            "classifier data", f"joints/mask/labels sizes differ: {joints.shape[0]}, {mask.shape[0]}, {labels.shape[0]}"
        )
    if joints.shape[0] == 0:
        raise MotionDataError("classifier data", "no samples")
    return joints, mask.bool(), labels.long()


def model_device(model: torch.nn.Module) -> torch.device:
    """Where ``model``'s weights are (CPU for a model without any)."""
    return next((p.device for p in model.parameters()), torch.device("cpu"))


def _on(batch: Batch, device: torch.device) -> Batch:
    joints, mask, labels = batch
    return joints.to(device), mask.to(device), labels.to(device)


def _batches(
    data: Batch | Iterable[Batch], batch_size: int, generator: torch.Generator, device: torch.device
) -> Iterator[Batch]:
    if isinstance(data, tuple):
        joints, mask, labels = _check_tensors(data)
        order = torch.randperm(joints.shape[0], generator=generator)  # CPU generator: the same order on any device
        for start in range(0, joints.shape[0], batch_size):
            idx = order[start : start + batch_size].to(joints.device)
            yield _on((joints[idx], mask[idx], labels[idx]), device)
    else:
        for batch in data:
            yield _on(_check_tensors(tuple(batch)), device)  # type: ignore[arg-type]


def fit_classifier(
    model: MotionClassifier,
    data: Batch | Iterable[Batch],
    epochs: int,
    lr: float = 1e-3,
    batch_size: int = 32,
    weight_decay: float = 0.0,
    seed: int = 0,
    standardize: bool = True,
) -> list[float]:
    """Adam on cross-entropy; returns the mean training loss of each epoch. Leaves the model in eval mode.

    Trains where the model is. ``standardize`` first sets the model's input statistics from the training data
    (one extra pass).
    """
    if epochs < 1:
        raise MotionDataError("fit_classifier", f"epochs must be >= 1, got {epochs}")
    if standardize:
        _set_input_stats(model, data)
    generator = torch.Generator().manual_seed(seed)
    optimizer = torch.optim.Adam(model.parameters(), lr=lr, weight_decay=weight_decay)
    history: list[float] = []
    model.train()
    for _ in range(epochs):
        total, count = 0.0, 0
        for joints, mask, labels in _batches(data, batch_size, generator, model_device(model)):
            loss = F.cross_entropy(model(joints, mask), labels)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            total += loss.item() * labels.shape[0]
            count += labels.shape[0]
        history.append(total / max(count, 1))
    model.eval()
    return history


def _set_input_stats(model: MotionClassifier, data: Batch | Iterable[Batch]) -> None:
    if isinstance(data, tuple):
        joints, mask, _ = _check_tensors(data)
    else:
        batches = [_check_tensors(tuple(b)) for b in data]  # type: ignore[arg-type]
        if not batches:
            raise MotionDataError("classifier data", "no batches")
        t_max = max(b[0].shape[1] for b in batches)
        joints = torch.cat([F.pad(b[0], (0, 0, 0, 0, 0, t_max - b[0].shape[1])) for b in batches])
        mask = torch.cat([F.pad(b[1], (0, t_max - b[1].shape[1])) for b in batches])
    device = model_device(model)
    model.set_input_stats(joints.to(device), mask.to(device))


@torch.no_grad()
def _run(model: MotionClassifier, joints: torch.Tensor, mask: torch.Tensor, batch_size: int, what: str) -> torch.Tensor:
    was_training = model.training
    model.eval()
    fn = model.features if what == "features" else model
    device = model_device(model)
    outputs = [
        fn(joints[i : i + batch_size].to(device), mask[i : i + batch_size].to(device)).cpu()
        for i in range(0, joints.shape[0], batch_size)
    ]
    model.train(was_training)
    return torch.cat(outputs)


def classifier_logits(
    model: MotionClassifier, joints: torch.Tensor, mask: torch.Tensor, batch_size: int = 64
) -> torch.Tensor:
    """Logits ``(N, C)`` on CPU, in eval mode, batched on the model's device."""
    return _run(model, joints, mask.bool(), batch_size, "logits")


def classifier_features(
    model: MotionClassifier, joints: torch.Tensor, mask: torch.Tensor, batch_size: int = 64
) -> torch.Tensor:
    """Pooled penultimate features ``(N, F)`` on CPU, in eval mode: the input of FMD."""
    return _run(model, joints, mask.bool(), batch_size, "features")


def classifier_accuracy(
    model: MotionClassifier, joints: torch.Tensor, mask: torch.Tensor, labels: torch.Tensor
) -> float:
    """CRA or SRA of ``model`` on labelled joints."""
    return recognition_accuracy(classifier_logits(model, joints, mask), labels)


# ---- the artefact ------------------------------------------------------------------------------------------

EVALUATORS_DIR = "evaluators"
EVALUATORS_JSON = "evaluators.json"


class EvaluatorsInfo(BaseModel):
    """Everything needed to rebuild the classifiers, and what they were fit and measured on."""

    model_config = ConfigDict(extra="forbid")

    version: int = 1
    content_classifier: dict[str, Any] | None = None
    style_classifier: dict[str, Any] | None = None
    content_labels: list[str] = Field(default_factory=list)
    style_labels: list[str] = Field(default_factory=list)
    corpus_fingerprint: str = Field("", description="The corpus whose train split they were fit on.")
    metrics: dict[str, float] = Field(default_factory=dict, description="Accuracy on the held-out split.")
    metrics_split: str = "test"


def evaluators_folder(path: str | Path) -> Path | None:
    """The evaluators at ``path``: the folder itself, or its ``evaluators/`` (a base-models folder); else None."""
    path = Path(path)
    for candidate in (path, path / EVALUATORS_DIR):
        if (candidate / EVALUATORS_JSON).is_file():
            return candidate
    return None


def save_evaluators(
    folder: str | Path,
    models: dict[str, MotionClassifier | None],
    labels: dict[str, list[str]],
    corpus_fingerprint: str,
    metrics: dict[str, float],
) -> Path:
    """Weights first, ``evaluators.json`` last (it marks a complete folder)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for name, model in models.items():
        if model is not None:
            save_module(model, folder / f"{name}.safetensors")
    info = EvaluatorsInfo(
        content_classifier=None
        if models[CONTENT_CLASSIFIER] is None
        else config_dict(models[CONTENT_CLASSIFIER].config),
        style_classifier=None if models[STYLE_CLASSIFIER] is None else config_dict(models[STYLE_CLASSIFIER].config),
        content_labels=labels["content"] if models[CONTENT_CLASSIFIER] is not None else [],
        style_labels=labels["style"] if models[STYLE_CLASSIFIER] is not None else [],
        corpus_fingerprint=corpus_fingerprint,
        metrics={k: v for k, v in sorted(metrics.items()) if k.endswith("classifier_accuracy")},
    )
    atomic_write_text(folder / EVALUATORS_JSON, info.model_dump_json(indent=2))
    return folder


def read_evaluators_info(folder: str | Path) -> EvaluatorsInfo:
    return read_json_model(Path(folder) / EVALUATORS_JSON, EvaluatorsInfo, "an evaluators folder (motionaug pretrain)")
