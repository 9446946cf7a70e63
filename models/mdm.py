"""MDM denoiser (Tevet et al. 2023, 'trans_enc'): a transformer encoder that predicts x0 from x_t.

Input (B, T, D) motion features, timestep (B,), text embedding (B, E), frame mask (B, T) -> x0_hat (B, T, D).
The timestep and text embeddings are summed into one extra first token; every frame attends over
[token, frames] with padding frames masked out as keys. The network knows nothing about sampling
(see augment.diffusion). Submodule names follow the official checkpoint (see models/mdm_checkpoint.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import torch
from torch import Tensor, nn

from motionaug.models.attention import run_encoder
from motionaug.schemas.errors import MotionDataError


@dataclass(frozen=True)
class MDMConfig:
    n_feats: int = 263  # HumanML3D feature size
    latent_dim: int = 512
    ff_size: int = 1024
    num_layers: int = 8
    num_heads: int = 4
    dropout: float = 0.1
    activation: str = "gelu"
    text_dim: int = 384  # 384: all-MiniLM-L6-v2; 512: CLIP ViT-B/32 (official MDM)
    cond_mask_prob: float = 0.1  # training-time text drop for classifier-free guidance
    max_len: int = 5000  # positional-encoding table size: must exceed both frames + 1 and the timesteps

    @classmethod
    def named(cls, name: str, **overrides: Any) -> MDMConfig:
        """``paper`` (MDM HumanML3D trans_enc), ``small`` (CPU work) or ``tiny`` (tests), with field overrides."""
        presets = {
            "paper": cls(latent_dim=512, ff_size=1024, num_layers=8, num_heads=4),
            "small": cls(latent_dim=256, ff_size=512, num_layers=4, num_heads=4),
            "tiny": cls(latent_dim=64, ff_size=128, num_layers=2, num_heads=4),
        }
        if name not in presets:
            raise MotionDataError("MDMConfig", f"unknown config {name!r} (choose from {sorted(presets)})")
        return replace(presets[name], **overrides)


class InputProcess(nn.Module):
    """Per-frame linear embedding of the features (shared with the motion encoder)."""

    def __init__(self, n_feats: int, latent_dim: int) -> None:
        super().__init__()
        self.poseEmbedding = nn.Linear(n_feats, latent_dim)

    def forward(self, x: Tensor) -> Tensor:
        return self.poseEmbedding(x)  # (B, T, F) -> (B, T, d)


class OutputProcess(nn.Module):
    """Per-frame linear read-out back to feature space."""

    def __init__(self, latent_dim: int, n_feats: int) -> None:
        super().__init__()
        self.poseFinal = nn.Linear(latent_dim, n_feats)

    def forward(self, h: Tensor) -> Tensor:
        return self.poseFinal(h)  # (B, T, d) -> (B, T, F)


def sinusoidal_table(max_len: int, dim: int) -> Tensor:
    """(max_len, dim) table: sin on even, cos on odd channels (Vaswani et al.; MDM's PositionalEncoding)."""
    position = torch.arange(max_len, dtype=torch.float32)[:, None]
    div_term = torch.exp(torch.arange(0, dim, 2, dtype=torch.float32) * (-math.log(10000.0) / dim))
    table = torch.zeros(max_len, dim)
    table[:, 0::2] = torch.sin(position * div_term)
    table[:, 1::2] = torch.cos(position * div_term)
    return table


class PositionalEncoding(nn.Module):
    """Adds the sinusoidal table along the sequence, then dropout. The table is recomputed, not stored."""

    def __init__(self, dim: int, dropout: float, max_len: int) -> None:
        super().__init__()
        self.dropout = nn.Dropout(dropout)
        self.register_buffer("pe", sinusoidal_table(max_len, dim), persistent=False)  # (max_len, d)

    def forward(self, x: Tensor) -> Tensor:
        return self.dropout(x + self.pe[: x.shape[1]].to(x.dtype))  # (B, L, d)


class TimestepEmbedder(nn.Module):
    """Linear-SiLU-Linear on the positional encoding of t."""

    def __init__(self, latent_dim: int) -> None:
        super().__init__()
        self.time_embed = nn.Sequential(nn.Linear(latent_dim, latent_dim), nn.SiLU(), nn.Linear(latent_dim, latent_dim))

    def forward(self, pe_t: Tensor) -> Tensor:
        return self.time_embed(pe_t)  # (B, d)


class MDM(nn.Module):
    """x0-predicting motion denoiser. ``forward(x_t, t, cond, mask, force_uncond) -> x0_hat``."""

    def __init__(self, config: MDMConfig) -> None:
        super().__init__()
        self.config = config
        d = config.latent_dim
        self.input_process = InputProcess(config.n_feats, d)
        self.sequence_pos_encoder = PositionalEncoding(d, config.dropout, config.max_len)
        self.embed_timestep = TimestepEmbedder(d)
        self.embed_text = nn.Linear(config.text_dim, d)
        layer = nn.TransformerEncoderLayer(
            d_model=d,
            nhead=config.num_heads,
            dim_feedforward=config.ff_size,
            dropout=config.dropout,
            activation=config.activation,
            batch_first=True,
        )
        self.seqTransEncoder = nn.TransformerEncoder(layer, num_layers=config.num_layers, enable_nested_tensor=False)
        self.output_process = OutputProcess(d, config.n_feats)

    def motion_embed(self, x: Tensor) -> Tensor:
        """Per-frame embedding of clean or noisy features (B, T, F) -> (B, T, d), without positions."""
        return self.input_process(x)

    def forward(
        self,
        x_t: Tensor,
        t: Tensor,
        cond: Tensor | dict[str, Tensor] | None = None,
        mask: Tensor | None = None,
        force_uncond: bool | Tensor = False,
    ) -> Tensor:
        """x_t (B, T, F), t (B,) long training timesteps, cond (B, E) or {"text_embed": (B, E)},
        mask (B, T) bool True = real frame, force_uncond bool or (B,) bool -> x0_hat (B, T, F)."""
        batch, frames, _ = x_t.shape
        self._check(x_t, t, mask)
        emb = self.embed_timestep(self.sequence_pos_encoder.pe[t])  # (B, d)
        text = self._text_embedding(cond, batch, x_t)  # (B, E)
        emb = emb + self.embed_text(self.mask_cond(text, force_uncond))  # (B, d)
        seq = torch.cat([emb[:, None], self.input_process(x_t)], dim=1)  # (B, 1+T, d)
        seq = self.sequence_pos_encoder(seq)
        h = run_encoder(self.seqTransEncoder, seq, self._keys(mask))[:, 1:]  # (B, T, d)
        return self.output_process(h)

    @staticmethod
    def _keys(mask: Tensor | None) -> Tensor | None:
        """(B, 1+T) True = a key frames may attend to: the condition token always, padding never."""
        if mask is None:
            return None
        return torch.cat([torch.ones(mask.shape[0], 1, dtype=torch.bool, device=mask.device), mask.bool()], dim=1)

    def mask_cond(self, text: Tensor, force_uncond: bool | Tensor = False) -> Tensor:
        """Zero the text embedding (the null condition) where forced, and per sample with cond_mask_prob in training."""
        if isinstance(force_uncond, Tensor):
            return text.masked_fill(force_uncond.view(-1, 1).to(text.device), 0.0)
        if force_uncond:
            return torch.zeros_like(text)
        if self.training and self.config.cond_mask_prob > 0:
            drop = torch.rand(text.shape[0], 1, device=text.device) < self.config.cond_mask_prob
            return text.masked_fill(drop, 0.0)
        return text

    def _text_embedding(self, cond: Tensor | dict[str, Tensor] | None, batch: int, like: Tensor) -> Tensor:
        """The (B, E) text embedding from a tensor or a dict; None means the null (all-zero) condition."""
        if isinstance(cond, dict):
            if "text_embed" not in cond:
                raise MotionDataError("MDM.forward", f"cond dict needs 'text_embed', got keys {sorted(cond)}")
            cond = cond["text_embed"]
        if cond is None:
            return torch.zeros(batch, self.config.text_dim, dtype=like.dtype, device=like.device)
        if cond.shape != (batch, self.config.text_dim):
            raise MotionDataError(
                "MDM.forward", f"text embedding {tuple(cond.shape)} != ({batch}, {self.config.text_dim})"
            )
        return cond.to(like.dtype)

    def _check(self, x_t: Tensor, t: Tensor, mask: Tensor | None) -> None:
        batch, frames, feats = x_t.shape
        if feats != self.config.n_feats:
            raise MotionDataError("MDM.forward", f"{feats} features, config expects {self.config.n_feats}")
        if frames + 1 > self.config.max_len:
            raise MotionDataError("MDM.forward", f"{frames} frames exceed max_len {self.config.max_len} - 1")
        if t.shape != (batch,):
            raise MotionDataError("MDM.forward", f"timesteps shape {tuple(t.shape)} != ({batch},)")
        if mask is not None and mask.shape != (batch, frames):
            raise MotionDataError("MDM.forward", f"mask shape {tuple(mask.shape)} != ({batch}, {frames})")
