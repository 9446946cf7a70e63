"""Content and style classifiers for evaluation (CRA, SRA) and the features FMD is computed on.

Temporal convolution networks over joints ``(B, T, J, 3)`` (metres, Y up, as ``recover_from_ric`` gives them), read
as ``joints_to_evaluator_input`` documents, since FMD depends on it: root-relative positions, their velocities and
the root velocity in m/s, each channel standardised with its training set's statistics (saved in the state dict).
With ``in_channels`` a classifier reads prepared channels ``(B, T, C)`` instead (the protocol's second judges), and
``standardise="clip"`` standardises each over the clip's own frames, so per-channel means and scales cannot move it.
Padded frames are zeroed before every convolution and left out of the temporal mean (no strides, no normalisation
across time), so a padded clip scores exactly as the same clip alone.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import torch
import torch.nn as nn


@dataclass(frozen=True)
class ClassifierConfig:
    n_classes: int
    n_joints: int = 22
    hidden: int = 128
    feat_dim: int = 128  # width of ``features`` (what FMD is computed on)
    n_blocks: int = 3  # dilations 1, 2, 4, ...: receptive field grows geometrically
    kernel: int = 5
    dropout: float = 0.1
    fps: float = 20.0  # turns per-frame displacements into m/s
    in_channels: int | None = None  # None: reads joints (B, T, J, 3); else prepared channels (B, T, in_channels)
    standardise: Literal["train", "clip"] = "train"  # by the training set's statistics, or over each clip
    clip_std_floor: float = 0.1  # "clip": least std of a channel, x its training-set std

    @property
    def in_dim(self) -> int:
        return 6 * self.n_joints + 3 if self.in_channels is None else self.in_channels


CLASSIFIER_SIZES: dict[str, dict[str, int | float]] = {
    "tiny": {"hidden": 32, "feat_dim": 32, "n_blocks": 2, "kernel": 3, "dropout": 0.0},
    "default": {},
}


def joints_to_evaluator_input(joints: torch.Tensor, fps: float = 20.0) -> torch.Tensor:
    """``(B, T, J, 3)`` joints -> ``(B, T, 6J + 3)``: root-relative positions, their velocities, root velocity."""
    if joints.ndim != 4 or joints.shape[-1] != 3:
        raise ValueError(f"evaluator input: expected joints (B, T, J, 3), got {tuple(joints.shape)}")
    root = joints[:, :, :1, :]  # (B, T, 1, 3)
    ground_plane = torch.tensor([1.0, 0.0, 1.0], dtype=joints.dtype, device=joints.device)
    local = joints - root * ground_plane  # (B, T, J, 3), heights kept
    local_vel = torch.zeros_like(local)
    local_vel[:, 1:] = (local[:, 1:] - local[:, :-1]) * fps
    root_vel = torch.zeros_like(root[:, :, 0])  # (B, T, 3)
    root_vel[:, 1:] = (root[:, 1:, 0] - root[:, :-1, 0]) * fps
    b, t = joints.shape[:2]
    return torch.cat([local.reshape(b, t, -1), local_vel.reshape(b, t, -1), root_vel], dim=-1)


def masked_mean(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean over time of ``(B, C, T)`` using only frames where ``mask (B, T)`` is True."""
    weights = mask.to(x.dtype).unsqueeze(1)  # (B, 1, T)
    return (x * weights).sum(dim=-1) / weights.sum(dim=-1).clamp_min(1.0)


class TemporalBlock(nn.Module):
    """Residual pair of dilated 'same' convolutions; each sees padded frames as zeros."""

    def __init__(self, channels: int, kernel: int, dilation: int, dropout: float) -> None:
        super().__init__()
        pad = dilation * (kernel - 1) // 2
        self.conv1 = nn.Conv1d(channels, channels, kernel, padding=pad, dilation=dilation)
        self.conv2 = nn.Conv1d(channels, channels, kernel, padding=pad, dilation=dilation)
        self.act = nn.GELU()
        self.dropout = nn.Dropout(dropout)

    def forward(self, x: torch.Tensor, keep: torch.Tensor) -> torch.Tensor:  # x (B, C, T), keep (B, 1, T)
        h = self.dropout(self.act(self.conv1(x))) * keep
        h = self.conv2(h)
        return self.act(x + h) * keep


class MotionClassifier(nn.Module):
    """TCN classifier: ``forward(joints, mask) -> logits``; ``features(joints, mask) -> (B, feat_dim)``."""

    def __init__(self, config: ClassifierConfig) -> None:
        super().__init__()
        if config.kernel % 2 == 0:
            raise ValueError(f"classifier: kernel must be odd to keep frames aligned, got {config.kernel}")
        self.config = config
        self.register_buffer("input_mean", torch.zeros(config.in_dim))
        self.register_buffer("input_std", torch.ones(config.in_dim))
        self.input_proj = nn.Conv1d(config.in_dim, config.hidden, 1)
        self.blocks = nn.ModuleList(
            TemporalBlock(config.hidden, config.kernel, 2**i, config.dropout) for i in range(config.n_blocks)
        )
        self.feature_head = nn.Sequential(nn.Linear(config.hidden, config.feat_dim), nn.GELU())
        self.classifier = nn.Linear(config.feat_dim, config.n_classes)

    def _check(self, joints: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
        if self.config.in_channels is not None:
            if joints.ndim != 3 or joints.shape[-1] != self.config.in_channels:
                raise ValueError(
                    f"classifier: expected channels (B, T, {self.config.in_channels}), got {tuple(joints.shape)}"
                )
        elif joints.ndim != 4 or joints.shape[2] != self.config.n_joints:
            raise ValueError(
                f"classifier: expected joints (B, T, {self.config.n_joints}, 3), got {tuple(joints.shape)}"
            )
        if mask is None:
            return torch.ones(joints.shape[:2], dtype=torch.bool, device=joints.device)
        if mask.shape != joints.shape[:2]:
            raise ValueError(f"classifier: mask {tuple(mask.shape)} does not match joints {tuple(joints.shape[:2])}")
        return mask.bool()

    def _input(self, x: torch.Tensor) -> torch.Tensor:
        """The per-frame channels ``(B, T, C)`` the network reads, before standardisation."""
        return joints_to_evaluator_input(x, self.config.fps) if self.config.in_channels is None else x

    def _standardised(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        if self.config.standardise == "train":
            return (x - self.input_mean) / self.input_std
        keep = mask.to(x.dtype).unsqueeze(-1)  # (B, T, 1)
        frames = keep.sum(dim=1, keepdim=True).clamp_min(1.0)
        mean = (x * keep).sum(dim=1, keepdim=True) / frames
        std = (((x - mean) ** 2 * keep).sum(dim=1, keepdim=True) / frames).sqrt()
        return (x - mean) / torch.maximum(std, self.config.clip_std_floor * self.input_std) * keep

    @torch.no_grad()
    def set_input_stats(self, joints: torch.Tensor, mask: torch.Tensor | None = None, min_std: float = 1e-2) -> None:
        """Per-channel mean/std of the network input over the real frames of a (training) set."""
        mask = self._check(joints, mask)
        x = self._input(joints)[mask]  # (frames, C_in)
        self.input_mean.copy_(x.mean(dim=0))
        self.input_std.copy_(x.std(dim=0, unbiased=False).clamp_min(min_std))

    def features(self, joints: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        """Pooled penultimate features ``(B, feat_dim)``; padded frames have no influence."""
        mask = self._check(joints, mask)
        keep = mask.to(joints.dtype).unsqueeze(1)  # (B, 1, T)
        x = self._standardised(self._input(joints), mask)
        h = self.input_proj(x.transpose(1, 2)) * keep  # (B, hidden, T); 1x1 conv, so masking here suffices
        for block in self.blocks:
            h = block(h, keep)
        return self.feature_head(masked_mean(h, mask))

    def forward(self, joints: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        return self.classifier(self.features(joints, mask))  # (B, n_classes)


def make_classifier(n_classes: int, n_joints: int = 22, size: str = "default", **overrides: object) -> MotionClassifier:
    """A classifier of a named size (``tiny`` for tests, ``default`` for evaluation)."""
    if size not in CLASSIFIER_SIZES:
        raise ValueError(f"classifier size: unknown {size!r}; choose from {sorted(CLASSIFIER_SIZES)}")
    config = replace(ClassifierConfig(n_classes=n_classes, n_joints=n_joints), **CLASSIFIER_SIZES[size])
    return MotionClassifier(replace(config, **overrides))  # type: ignore[arg-type]


def content_classifier(n_contents: int, n_joints: int = 22, size: str = "default") -> MotionClassifier:
    """Recognises what is done (walk, kick, ...): CRA is its accuracy on stylised outputs."""
    return make_classifier(n_contents, n_joints, size)


def style_classifier(n_styles: int, n_joints: int = 22, size: str = "default") -> MotionClassifier:
    """Recognises how it is done (angry, old, ...): SRA is its accuracy against the target style."""
    return make_classifier(n_styles, n_joints, size)
