"""Load an official MDM checkpoint (GuyTevet/motion-diffusion-model, HumanML3D 'trans_enc') into ``models.mdm.MDM``.

Our modules keep the official parameter names and shapes (the official forward runs sequence-first, ours
batch-first, which changes no shape), so the map is the identity on ``input_process``, ``embed_timestep``,
``embed_text``, ``seqTransEncoder.layers.N`` and ``output_process``. Skipped: ``clip_model.*`` (the frozen text
encoder lives elsewhere) and the sinusoidal position tables, which ours recomputes and checks equal to them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import torch
from torch import Tensor

from motionaug.models.mdm import MDM
from motionaug.schemas.errors import MotionDataError

SKIPPED_PREFIXES = ("clip_model.",)
PE_KEYS = ("sequence_pos_encoder.pe", "embed_timestep.sequence_pos_encoder.pe")


@dataclass(frozen=True)
class LoadReport:
    """What happened to each key: loaded into ours, skipped on purpose, left missing, or not understood."""

    loaded: tuple[str, ...]
    skipped: tuple[str, ...]
    missing: tuple[str, ...]
    unexpected: tuple[str, ...]


def _unwrap(checkpoint: Mapping[str, object]) -> Mapping[str, Tensor]:
    """The parameter dict of a raw state dict or of a training checkpoint holding one ('model_avg' / 'model')."""
    for wrapper in ("model_avg", "model", "state_dict"):
        inner = checkpoint.get(wrapper)
        if isinstance(inner, Mapping):
            return inner  # type: ignore[return-value]
    return checkpoint  # type: ignore[return-value]


def _check_pe(model: MDM, key: str, value: Tensor) -> None:
    """The official table is (max_len, 1, d); it must equal ours where both are defined."""
    table = model.sequence_pos_encoder.pe
    theirs = value.reshape(value.shape[0], -1).float()
    if theirs.shape[1] != table.shape[1]:
        raise MotionDataError(key, f"positional table width {theirs.shape[1]} != latent_dim {table.shape[1]}")
    n = min(theirs.shape[0], table.shape[0])
    if not torch.allclose(theirs[:n], table[:n].cpu(), atol=1e-4):
        raise MotionDataError(key, "positional-encoding table differs from the sinusoidal one this model computes")


def load_official_mdm_state_dict(model: MDM, state_dict: Mapping[str, object], strict: bool = True) -> LoadReport:
    """Copy an official MDM state dict into ``model``; raise MotionDataError on shape mismatch (and, if strict,
    on missing or unexpected keys). ``module.`` prefixes (DataParallel) are stripped.

    Key map (official -> ours)::

        input_process.poseEmbedding.{weight,bias}      -> same name ((d, 263), (d,))
        embed_timestep.time_embed.{0,2}.{weight,bias}  -> same name (Linear-SiLU-Linear, (d, d))
        embed_text.{weight,bias}                       -> same name ((d, 512) for CLIP ViT-B/32)
        seqTransEncoder.layers.N.*                     -> same name (nn.TransformerEncoderLayer, post-norm, gelu)
        output_process.poseFinal.{weight,bias}         -> same name ((263, d), (263,))
        skipped: clip_model.*, sequence_pos_encoder.pe, embed_timestep.sequence_pos_encoder.pe ((5000, 1, d))
    """
    source = {k.removeprefix("module."): v for k, v in _unwrap(state_dict).items()}
    ours = model.state_dict()
    loaded, skipped, unexpected, new_state = [], [], [], {}
    for key, value in source.items():
        if key.startswith(SKIPPED_PREFIXES):
            skipped.append(key)
        elif key in PE_KEYS:
            _check_pe(model, key, torch.as_tensor(value))
            skipped.append(key)
        elif key in ours:  # official and our names coincide (see the module docstring)
            value = torch.as_tensor(value)
            if value.shape != ours[key].shape:
                raise MotionDataError(key, f"shape {tuple(value.shape)} != model's {tuple(ours[key].shape)}")
            new_state[key] = value
            loaded.append(key)
        else:
            unexpected.append(key)
    missing = sorted(set(ours) - set(new_state))
    if strict and (missing or unexpected):
        raise MotionDataError(
            "official MDM checkpoint",
            f"{len(missing)} missing keys (first {missing[:3]}), {len(unexpected)} unexpected (first {unexpected[:3]})",
        )
    model.load_state_dict(new_state, strict=False)
    return LoadReport(tuple(loaded), tuple(skipped), tuple(missing), tuple(unexpected))
