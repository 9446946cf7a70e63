"""The forward pass of an ``nn.TransformerEncoder`` (post-norm, batch-first), with attention kernels picked for CPU.

Why not call the encoder itself: on CPU, PyTorch's own paths are slow for our lengths (<= 197 tokens, heads of
32-128). With a key-padding mask and no gradients its fused fast path spends most of a forward in
``_masked_softmax`` (bf16), where ``scaled_dot_product_attention`` with a broadcast (B, 1, 1, L) mask does not; with
gradients the fused flash kernel's CPU backward is slower than a plain matmul-softmax-matmul. The modules (so the
state-dict keys, the official-checkpoint mapping and the LoRA adapters) stay exactly those of
``nn.TransformerEncoder``; only the order of the maths is ours, and ``tests/test_mdm.py`` checks the two agree.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn


def run_encoder(encoder: nn.TransformerEncoder, x: Tensor, keep: Tensor | None = None) -> Tensor:
    """x (B, L, d); keep (B, L) bool, True = a key every query may attend to (None: all). -> (B, L, d).

    Every row of ``keep`` needs at least one True (our callers always keep their condition or pooling token).
    """
    attn_mask = None if keep is None or bool(keep.all()) else keep[:, None, None, :].bool()
    for layer in encoder.layers:
        x = _layer(layer, x, attn_mask)
    return x if encoder.norm is None else encoder.norm(x)


def _layer(layer: nn.TransformerEncoderLayer, x: Tensor, attn_mask: Tensor | None) -> Tensor:
    """Post-norm block, as ``nn.TransformerEncoderLayer(norm_first=False)`` and the official MDM."""
    if layer.norm_first:
        raise ValueError("run_encoder: pre-norm layers are not supported (MDM and the motion encoder are post-norm)")
    x = layer.norm1(x + layer.dropout1(_self_attention(layer.self_attn, x, attn_mask)))
    return layer.norm2(x + layer.dropout2(layer.linear2(layer.dropout(layer.activation(layer.linear1(x))))))


def _self_attention(attn: nn.MultiheadAttention, x: Tensor, attn_mask: Tensor | None) -> Tensor:
    b, length, d = x.shape
    heads = attn.num_heads
    qkv = F.linear(x, attn.in_proj_weight, attn.in_proj_bias)  # reads the LoRA parametrisation when there is one
    q, k, v = qkv.view(b, length, 3, heads, d // heads).permute(2, 0, 3, 1, 4)  # each (B, H, L, d/H)
    dropout = attn.dropout if attn.training else 0.0
    if torch.is_grad_enabled():
        out = _plain_attention(q, k, v, attn_mask, dropout)
    else:
        out = F.scaled_dot_product_attention(q, k, v, attn_mask=attn_mask, dropout_p=dropout)
    return attn.out_proj(out.transpose(1, 2).reshape(b, length, d))


def _plain_attention(q: Tensor, k: Tensor, v: Tensor, attn_mask: Tensor | None, dropout: float) -> Tensor:
    """softmax(q k^T / sqrt(d) masked) v: the same maths as SDPA, with a fast CPU backward."""
    scores = (q @ k.transpose(-1, -2)) * (q.shape[-1] ** -0.5)
    if attn_mask is not None:
        scores = scores.masked_fill(~attn_mask, float("-inf"))
    weights = scores.softmax(dim=-1)
    if dropout > 0:
        weights = F.dropout(weights, p=dropout)
    return weights @ v
