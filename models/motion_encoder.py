"""Motion encoder that maps a motion into the caption embedding space (Hu et al., CGF 2024, sec. 3.4.1).

It reads motions through the *same* embedding layer as the denoiser's input layer, so the semantic loss that
compares a motion with its caption (Eq. 8) shapes a representation the denoiser also uses. A learnable pooling token
is prepended; after N transformer-encoder layers its output is projected to the text embedding size. Share the layer
with ``MotionEncoder(config, mdm.input_process)`` (batch-first; ``config.d_model`` must equal
``MDMConfig.latent_dim``); a sequence-first layer, as in the official MDM code, works with ``embed_layout="tbd"``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

import torch
import torch.nn as nn
import torch.nn.functional as F

from motionaug.models.attention import run_encoder

EmbedLayout = Literal["btd", "tbd"]


@dataclass(frozen=True)
class MotionEncoderConfig:
    input_dim: int = 263  # HumanML3D features; only used when the encoder builds its own embedding
    d_model: int = 512  # must equal the shared embedding's output width (MDMConfig.latent_dim)
    n_layers: int = 4
    n_heads: int = 4
    ff_dim: int = 1024
    dropout: float = 0.1
    text_dim: int = 384  # MiniLM; 512 for CLIP ViT-B/32
    max_len: int = 1024  # frames (+1 token) the positional table covers

    @classmethod
    def named(cls, size: str, **overrides: object) -> MotionEncoderConfig:
        """``tiny`` for tests, ``small`` for CPU experiments, ``paper`` sized like MDM's transformer."""
        try:
            base = NAMED_SIZES[size]
        except KeyError:
            raise ValueError(f"motion encoder size: unknown {size!r}; choose from {sorted(NAMED_SIZES)}") from None
        return replace(base, **overrides)  # type: ignore[arg-type]


NAMED_SIZES: dict[str, MotionEncoderConfig] = {
    "tiny": MotionEncoderConfig(d_model=64, n_layers=1, n_heads=4, ff_dim=128, dropout=0.0),
    "small": MotionEncoderConfig(d_model=256, n_layers=2, n_heads=4, ff_dim=512),
    "paper": MotionEncoderConfig(d_model=512, n_layers=4, n_heads=4, ff_dim=1024),
}


class SinusoidalPositions(nn.Module):
    """Fixed sin/cos positions added to a batch-first sequence (Vaswani et al.)."""

    def __init__(self, d_model: int, max_len: int, dropout: float) -> None:
        super().__init__()
        position = torch.arange(max_len, dtype=torch.float32).unsqueeze(1)
        div = torch.exp(torch.arange(0, d_model, 2, dtype=torch.float32) * (-math.log(10000.0) / d_model))
        table = torch.zeros(max_len, d_model)
        table[:, 0::2] = torch.sin(position * div)
        table[:, 1::2] = torch.cos(position * div)[:, : d_model // 2]
        self.register_buffer("table", table, persistent=False)
        self.dropout = nn.Dropout(dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # (B, T, d)
        if x.shape[1] > self.table.shape[0]:
            raise ValueError(f"motion encoder: {x.shape[1]} positions exceed max_len {self.table.shape[0]}")
        return self.dropout(x + self.table[: x.shape[1]])


class FrameEmbedding(nn.Module):
    """Per-frame linear embedding named like MDM's ``InputProcess`` (``poseEmbedding``), so a standalone
    encoder and one sharing the denoiser's layer have the same state-dict keys (``embed.poseEmbedding.*``)."""

    def __init__(self, input_dim: int, d_model: int) -> None:
        super().__init__()
        self.poseEmbedding = nn.Linear(input_dim, d_model)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.poseEmbedding(x)  # (B, T, F) -> (B, T, d)


class MotionEncoder(nn.Module):
    """``forward(x (B, T, D), mask (B, T) bool, True = real frame) -> (B, text_dim)``."""

    def __init__(
        self, config: MotionEncoderConfig, embed: nn.Module | None = None, embed_layout: EmbedLayout = "btd"
    ) -> None:
        super().__init__()
        if embed_layout not in ("btd", "tbd"):
            raise ValueError(f"motion encoder: embed_layout must be 'btd' or 'tbd', got {embed_layout!r}")
        self.config = config
        self.embed = embed if embed is not None else FrameEmbedding(config.input_dim, config.d_model)
        self.embed_layout = embed_layout
        self.pool_token = nn.Parameter(torch.randn(1, 1, config.d_model) * 0.02)
        self.positions = SinusoidalPositions(config.d_model, config.max_len + 1, config.dropout)
        layer = nn.TransformerEncoderLayer(
            config.d_model, config.n_heads, config.ff_dim, config.dropout, activation="gelu", batch_first=True
        )
        self.encoder = nn.TransformerEncoder(layer, config.n_layers, enable_nested_tensor=False)
        self.project = nn.Linear(config.d_model, config.text_dim)

    def _embed(self, x: torch.Tensor) -> torch.Tensor:
        if self.embed_layout == "tbd":
            return self.embed(x.transpose(0, 1)).transpose(0, 1)
        return self.embed(x)

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        b, t, _ = x.shape
        if mask is None:
            mask = torch.ones(b, t, dtype=torch.bool, device=x.device)
        h = self._embed(x)  # (B, T, d)
        h = torch.cat([self.pool_token.expand(b, 1, -1), h], dim=1)  # (B, 1+T, d)
        h = self.positions(h)
        keep = torch.cat([torch.ones(b, 1, dtype=torch.bool, device=x.device), mask.bool()], dim=1)
        h = run_encoder(self.encoder, h, keep)  # padded frames are never attended to
        return self.project(h[:, 0])  # (B, text_dim)


def semantic_loss(motion_feat: torch.Tensor, text_feat: torch.Tensor, delta: float = 1e-6) -> torch.Tensor:
    """Eq. 8: mean of ``1 - <m, t> / (|m| |t| + delta)``; delta keeps a zero vector finite."""
    dot = (motion_feat * text_feat).sum(dim=-1)
    denom = motion_feat.norm(dim=-1) * text_feat.norm(dim=-1) + delta
    return (1.0 - dot / denom).mean()


def cosine_similarity(motion_feat: torch.Tensor, text_feat: torch.Tensor) -> torch.Tensor:
    """Row-wise cosine, for reporting alignment (no delta: F.cosine_similarity clamps norms)."""
    return F.cosine_similarity(motion_feat, text_feat, dim=-1)
