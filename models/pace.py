"""A pace regressor: how much faster (or slower) the content clip's root moves once it takes the example's style.

A style changes the ground speed as well as the posture: a depressed or old walk covers less ground than a
neutral one, a childlike one more. The diffusion transfer keeps the content's root path by inpainting, and so
its speed; this network tells the sampler by how much to scale it. Input: the content clip and the style example,
each summarised by the mean and standard deviation over its valid frames of every normalised feature channel
(which carry the posture, the step amplitude and the speeds). Output: log(pace of the transfer / pace of the
content). Not in the UMSD paper (its outputs keep the content's trajectory).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn


def clip_summary(x: Tensor, mask: Tensor) -> Tensor:
    """(B, 2F): mean and standard deviation over the valid frames (``mask`` (B, T) True) of each channel of
    ``x`` (B, T, F)."""
    weights = mask.to(x.dtype).unsqueeze(-1)
    count = weights.sum(dim=1).clamp(min=1.0)
    mean = (x * weights).sum(dim=1) / count
    var = (((x - mean.unsqueeze(1)) ** 2) * weights).sum(dim=1) / count
    return torch.cat([mean, var.clamp(min=0.0).sqrt()], dim=-1)


class PaceNet(nn.Module):
    """MLP on [summary(content), summary(style example)] -> log pace ratio (B,)."""

    def __init__(self, n_feats: int, hidden: int = 128):
        super().__init__()
        self.n_feats, self.hidden = n_feats, hidden
        self.mlp = nn.Sequential(
            nn.Linear(4 * n_feats, hidden),
            nn.GELU(),
            nn.Linear(hidden, hidden),
            nn.GELU(),
            nn.Linear(hidden, 1),
        )

    def forward(self, content_summary: Tensor, style_summary: Tensor) -> Tensor:
        return self.mlp(torch.cat([content_summary, style_summary], dim=-1)).squeeze(-1)
