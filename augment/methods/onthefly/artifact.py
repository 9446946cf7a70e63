"""The artefact of a style: ``artifact.json`` (how it was made) + ``weights.safetensors`` (the transfer model).

Only LoRA adapters (and trained biases) are stored for a LoRA fine-tune, else the whole transfer model; an artefact
fits only the base models it was tuned from (``base_fingerprint``).
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict
from torch import Tensor, nn

from motionaug.augment.methods.common import files_fingerprint, read_artifact_json, read_tensors
from motionaug.augment.methods.onthefly.finetuning import lora_bias_parameters
from motionaug.augment.methods.onthefly.params import METHOD_NAME, OnTheFlyRecipe
from motionaug.augment.training.base_models import BASE_JSON, PRIOR, BaseModels, load_module
from motionaug.models.lora import (
    apply_lora,
    is_lora_key,
    load_biases,
    load_lora_state_dict,
    lora_state_dict,
    merge_lora,
)
from motionaug.schemas.styles import StyleSpec


class OnTheFlyArtifact(BaseModel):
    """``artifact.json``: enough to rebuild the transfer model over the same base models, and how it was made."""

    model_config = ConfigDict(extra="forbid")

    version: int = 1
    method: str = METHOD_NAME
    style: StyleSpec
    params: OnTheFlyRecipe
    base_fingerprint: str
    weights: Literal["full", "lora"]
    weights_bytes: int
    full_model_bytes: int
    trainable_parameters: int
    pool_clips: int
    pool_skipped: int
    tempo: float = 1.0
    tempo_note: str = ""
    loss_curve: list[dict[str, float]]


def base_fingerprint(base_dir: Path) -> str:
    """sha256 of base.json and the prior's weights: an artefact only fits the prior it was tuned from."""
    return files_fingerprint(Path(base_dir), (BASE_JSON, f"{PRIOR}.safetensors"), "base-models file")


def weights_state(model: nn.Module, params: OnTheFlyRecipe) -> dict[str, Tensor]:
    """What the artefact stores: only adapter tensors for LoRA, else the whole transfer model."""
    if params.lora_rank > 0:
        state = {**lora_state_dict(model), **lora_bias_parameters(model, params)}
    else:
        state = model.state_dict()
    return {k: v.detach().cpu().contiguous().clone() for k, v in state.items()}  # safetensors writes from CPU


def read_artifact(artifact_dir: Path) -> OnTheFlyArtifact:
    return read_artifact_json(artifact_dir, OnTheFlyArtifact, METHOD_NAME, "an on-the-fly artefact")


def rebuild_transfer_model(base: BaseModels, info: OnTheFlyArtifact, weights: Path, merge: bool = False) -> nn.Module:
    """The prior copy with the artefact's weights (adapters re-attached, optionally merged for speed)."""
    model = copy.deepcopy(base.prior)
    if info.weights == "full":
        load_module(model, weights)
        return model.eval().requires_grad_(False)
    state = read_tensors(weights)
    rank, targets = info.params.lora_rank, info.params.lora_targets
    apply_lora(model, rank, info.params.lora_alpha or float(rank), targets)
    load_lora_state_dict(model, {k: v for k, v in state.items() if is_lora_key(k)})
    load_biases(lora_bias_parameters(model, info.params), {k: v for k, v in state.items() if not is_lora_key(k)})
    if merge:
        merge_lora(model)
    return model.eval().requires_grad_(False)
