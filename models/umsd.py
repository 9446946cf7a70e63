"""UMSD (Qian et al., ACM MM 2025): UMSD attention + the Motion Style Mamba (MSM) denoiser, predicting x0.

Equation numbers refer to "Unified Motion Style Diffusion" (sec. 3). ``UmsdAttention`` (Eqs. 2-5) lets the clean
content and style sequences exchange information, so the condition is computed once per clip and reused at every
sampling step. ``MsmDenoiser`` (Eqs. 6-9) runs noisy-frame, timestep and condition tokens through MSM blocks (causal
conv, bidirectional SSM via ``BiMamba``, attention, feed-forward) and reads the noisy-frame tokens out as x0, as MDM
does; ``TransformerDenoiser`` is sec. 4.5's ablation with standard layers. Every part of Eq. 6 is packed (valid
tokens first, padding only at the end) so one sample's conv, SSM and norms never see padding or its batch mates.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, NamedTuple

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from motionaug.models.attention import run_encoder
from motionaug.models.mdm import sinusoidal_table
from motionaug.models.selective_scan import BiMamba, causal_conv1d
from motionaug.schemas.errors import MotionDataError

NUM_TIMESTEPS = 1000  # T = 1000 diffusion steps (sec. 3.1)
DENOISERS = ("msm", "transformer")
SEGMENTS = ("x_t", "time", "content", "style")  # the parts of Eq. 6's concatenation, in order


@dataclass(frozen=True)
class UmsdConfig:
    """Sizes and ablation switches. The paper gives no widths; these defaults are CPU-sized."""

    n_feats: int = 263  # HumanML3D feature size
    d_model: int = 64  # width of every token (UMSD attention, MSM blocks, MHA, FFN in/out)
    n_heads: int = 4  # heads of every attention (Eqs. 2-4 and 8)
    ff_size: int = 256  # FFN hidden width (Eq. 9)
    msm_blocks: int = 3  # iterations of Eq. 7 (i in {1, 2, 3} in the paper)
    d_state: int = 8  # SSM state size N (Mamba's default: 16)
    expand: int = 2  # SSM inner width = expand * d_model (Mamba's default)
    d_conv: int = 4  # width of the causal conv mu (Mamba's default)
    dropout: float = 0.1
    max_len: int = 1024  # longest content / style / noisy sequence (positional-encoding table)
    denoiser: str = "msm"  # "msm" (sec. 3.3) or "transformer" (ablation, sec. 4.5)
    use_ssm: bool = True  # False: Eq. 7 without Phi+ / Phi- (the linear + causal conv branch only)
    use_mha: bool = True  # False: Eq. 8 without its MHA term
    align_content: bool = False  # True: also add each content token to the noisy token of its frame (not in the paper)

    def __post_init__(self) -> None:
        if self.denoiser not in DENOISERS:
            raise ValueError(f"denoiser must be one of {DENOISERS}, got {self.denoiser!r}")
        if min(self.n_feats, self.d_model, self.n_heads, self.ff_size, self.msm_blocks, self.d_state) < 1:
            raise ValueError("sizes must be positive")
        if self.d_model % self.n_heads:
            raise ValueError(f"d_model {self.d_model} is not a multiple of n_heads {self.n_heads}")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"dropout {self.dropout} outside [0, 1)")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> UmsdConfig:
        unknown = sorted(set(data) - set(cls.__dataclass_fields__))
        if unknown:
            raise ValueError(f"unknown UmsdConfig fields {unknown}")
        return cls(**data)


# ---- building blocks ----------------------------------------------------------------------------------------


def attend(q: Tensor, k: Tensor, v: Tensor, key_mask: Tensor | None) -> Tensor:
    """softmax(q k^T / sqrt(d)) v over (B, H, L, d_head), keys masked by ``key_mask`` (B, Lk) True = real.

    With gradients: plain matmul-softmax-matmul (its CPU backward is much faster than the fused kernel's, see
    ``models.attention``); without: ``scaled_dot_product_attention``.
    """
    mask = None if key_mask is None else key_mask[:, None, None, :]
    if not torch.is_grad_enabled():
        return F.scaled_dot_product_attention(q, k, v, attn_mask=mask)
    scores = (q @ k.transpose(-1, -2)) * (q.shape[-1] ** -0.5)
    if mask is not None:
        scores = scores.masked_fill(~mask, float("-inf"))
    return scores.softmax(dim=-1) @ v


class Attention(nn.Module):
    """Multi-head attention with the query from one sequence and keys/values from another (Eqs. 2-4, 8).

    ``query`` (B, Lq, d), ``source`` (B, Lk, d), ``source_mask`` (B, Lk) -> (B, Lq, d). Q, K and V are linear
    projections (sec. 3.2); self attention is ``source = query``. No dropout on the attention weights: drawing the
    (B, H, Lq, Lk) mask cost a quarter of a CPU training step.
    """

    def __init__(self, d_model: int, n_heads: int) -> None:
        super().__init__()
        self.n_heads = n_heads
        self.q_proj = nn.Linear(d_model, d_model)
        self.kv_proj = nn.Linear(d_model, 2 * d_model)
        self.out_proj = nn.Linear(d_model, d_model)

    def forward(self, query: Tensor, source: Tensor, source_mask: Tensor | None) -> Tensor:
        b, lq, d = query.shape
        h = self.n_heads
        q = self.q_proj(query).view(b, lq, h, d // h).transpose(1, 2)
        k, v = self.kv_proj(source).view(b, source.shape[1], 2, h, d // h).permute(2, 0, 3, 1, 4)
        out = attend(q, k, v, source_mask)
        return self.out_proj(out.transpose(1, 2).reshape(b, lq, d))


class InstanceNorm(nn.Module):
    """IN(.) of Eqs. 7-9: per sample and channel, zero mean and unit variance over the real tokens, then a
    learned per-channel scale and shift (``nn.InstanceNorm1d(affine=True)`` with a padding mask). Padding -> 0."""

    def __init__(self, d_model: int, eps: float = 1e-5) -> None:
        super().__init__()
        self.eps = eps
        self.weight = nn.Parameter(torch.ones(d_model))
        self.bias = nn.Parameter(torch.zeros(d_model))

    def forward(self, x: Tensor, mask: Tensor) -> Tensor:
        """x (B, L, d), mask (B, L) bool."""
        dtype = x.dtype
        x = x.float()
        keep = mask[..., None].float()
        count = keep.sum(dim=1, keepdim=True).clamp(min=1.0)
        mean = (x * keep).sum(dim=1, keepdim=True) / count
        var = ((x - mean).square() * keep).sum(dim=1, keepdim=True) / count
        y = (x - mean) * torch.rsqrt(var + self.eps) * self.weight + self.bias
        return (y * keep).to(dtype)


class ConvMixer(nn.Module):
    """The ``use_ssm=False`` ablation of Eq. 7's right branch: ``BiMamba`` without Phi+ and Phi- (in_proj, causal
    conv mu, SiLU, gate, out_proj), so only the SSMs are removed."""

    def __init__(self, d_model: int, expand: int, d_conv: int) -> None:
        super().__init__()
        d_inner = expand * d_model
        self.in_proj = nn.Linear(d_model, 2 * d_inner, bias=False)
        self.conv1d = nn.Conv1d(d_inner, d_inner, d_conv, groups=d_inner)
        self.out_proj = nn.Linear(d_inner, d_model, bias=False)

    def forward(self, hidden: Tensor, mask: Tensor | None = None) -> Tensor:
        x, z = self.in_proj(hidden).chunk(2, dim=-1)
        if mask is not None:
            x = x * mask[..., None].to(x.dtype)
        x = F.silu(causal_conv1d(self.conv1d, x, anticausal=False))
        return self.out_proj(x * F.silu(z))


# ---- UMSD attention (sec. 3.2) --------------------------------------------------------------------------------


class UmsdCondition(NamedTuple):
    """Z^out of Eq. 5, split back into its content and style parts, with their masks."""

    content: Tensor  # (B, Tc, d)
    content_mask: Tensor  # (B, Tc) bool
    style: Tensor  # (B, Ts, d)
    style_mask: Tensor  # (B, Ts) bool


class UmsdAttention(nn.Module):
    """Eqs. 2-5 over the position-encoded content and style motions; every stage runs in both directions.

    The paper writes the style direction (style queries) and says the content direction "follows the same
    steps"; each direction and stage has its own projections. Stages: cross attention (Eq. 2), self attention
    within each sequence (Eq. 3), cross attention again (Eq. 4); no residuals between them, and the output is
    Z^u1 + Linear(Z^u2) (Eq. 5, where the paper's "LN" is a linear layer).
    """

    def __init__(self, config: UmsdConfig) -> None:
        super().__init__()
        d, h = config.d_model, config.n_heads
        self.content_in = nn.Linear(config.n_feats, d)
        self.style_in = nn.Linear(config.n_feats, d)
        self.dropout = nn.Dropout(config.dropout)
        self.cross1_style, self.cross1_content = Attention(d, h), Attention(d, h)  # Eq. 2
        self.self_style, self.self_content = Attention(d, h), Attention(d, h)  # Eq. 3
        self.cross2_style, self.cross2_content = Attention(d, h), Attention(d, h)  # Eq. 4
        self.out = nn.Linear(d, d)  # Eq. 5's "LN", a linear layer

    def forward(self, content: Tensor, content_mask: Tensor, style: Tensor, style_mask: Tensor, pe: Tensor):
        """content (B, Tc, F), style (B, Ts, F), masks (B, T*) bool, pe (max_len, d) -> ``UmsdCondition``."""
        zc1 = self.dropout(self.content_in(content) + pe[: content.shape[1]])  # Z^c1: position-encoded content
        zs1 = self.dropout(self.style_in(style) + pe[: style.shape[1]])  # Z^s1: position-encoded style
        zs2 = self.cross1_style(zs1, zc1, content_mask)  # Eq. 2: softmax(Q_s1 K_c1^T / sqrt(d)) V_c1
        zc2 = self.cross1_content(zc1, zs1, style_mask)  # ... and content queries on the style
        zs3 = self.self_style(zs2, zs2, style_mask)  # Eq. 3: self attention within the style
        zc3 = self.self_content(zc2, zc2, content_mask)  # ... and within the content
        zs4 = self.cross2_style(zs3, zc3, content_mask)  # Eq. 4: softmax(Q_s3 K_c3^T / sqrt(d)) V_c3
        zc4 = self.cross2_content(zc3, zs3, style_mask)
        # Eq. 5: Z^out = Z^u1 + LN(Z^u2) with Z^u = [Z^c; Z^s] along time: the linear acts per token, so the two
        # parts are kept apart here and concatenated in Eq. 6.
        out_c = (zc1 + self.out(zc4)) * content_mask[..., None].to(zc1.dtype)
        out_s = (zs1 + self.out(zs4)) * style_mask[..., None].to(zs1.dtype)
        return UmsdCondition(out_c, content_mask, out_s, style_mask)


# ---- denoisers (sec. 3.3) -------------------------------------------------------------------------------------


class MsmBlock(nn.Module):
    """One iteration of Eq. 7: u = LN(D^{i-1}); D_r^i = IN(Phi+(mu(u)) + Phi-(mu(u))); D^i = IN(u) + D_r^i.

    ``BiMamba`` is mu (causal depthwise conv) + Phi+ + Phi- summed, with Mamba's own input/gate/output
    projections around them; "LN" is a linear layer in the paper.
    """

    def __init__(self, config: UmsdConfig) -> None:
        super().__init__()
        d = config.d_model
        self.linear = nn.Linear(d, d)
        if config.use_ssm:
            self.mixer: nn.Module = BiMamba(d, config.d_state, config.expand, config.d_conv)
        else:
            self.mixer = ConvMixer(d, config.expand, config.d_conv)
        self.norm_skip = InstanceNorm(d)
        self.norm_mix = InstanceNorm(d)

    def forward(self, h: Tensor, mask: Tensor) -> Tensor:
        u = self.linear(h)
        return self.norm_skip(u, mask) + self.norm_mix(self.mixer(u, mask), mask)


class MsmDenoiser(nn.Module):
    """Eqs. 7-9 over the packed Eq. 6 tokens: (B, L, d), mask (B, L) -> (B, L, d).

    D_in = concat(m_t, MLP(t), Z_out) along time (Eq. 6): one token per noisy frame, one timestep token, one per
    condition frame. Each of ``msm_blocks`` blocks is Eq. 7 (linear, causal conv, forward + backward SSM, instance
    norms, the residual D^res), then multi-head attention (Eq. 8) and a feed-forward network (Eq. 9).
    """

    def __init__(self, config: UmsdConfig) -> None:
        super().__init__()
        d = config.d_model
        self.input = nn.Linear(d, d)  # Eq. 7: D^0 = LN(D_in), also the residual term of D^res
        self.blocks = nn.ModuleList(MsmBlock(config) for _ in range(config.msm_blocks))
        self.attn_in = nn.Linear(d, d)  # Eq. 8's LN(D^res)
        self.attn = Attention(d, config.n_heads) if config.use_mha else None
        self.norm_attn = InstanceNorm(d)
        self.ffn = nn.Sequential(
            nn.Linear(d, config.ff_size), nn.GELU(), nn.Dropout(config.dropout), nn.Linear(config.ff_size, d)
        )
        self.norm_out = InstanceNorm(d)

    def forward(self, d_in: Tensor, mask: Tensor) -> Tensor:
        d0 = self.input(d_in)
        h = d0
        for block in self.blocks:
            h = block(h, mask)  # Eq. 7, i = 1..msm_blocks
        d_res = d0 + h  # Eq. 7: D^res = LN(D_in) + D^3
        u = self.attn_in(d_res)
        sigma = self.norm_attn(u, mask)  # Eq. 8: sigma = IN(LN(D^res)) + MHA(LN(D^res))
        if self.attn is not None:
            sigma = sigma + self.attn(u, u, mask)
        return self.ffn(sigma) + self.norm_out(sigma, mask)  # Eq. 9: D_out = FFN(sigma) + IN(sigma)


class TransformerDenoiser(nn.Module):
    """Ablation: ``msm_blocks + 1`` post-norm transformer encoder layers (as many token-mixing layers as the MSM
    denoiser's SSM blocks plus its MHA), same width and FFN size."""

    def __init__(self, config: UmsdConfig) -> None:
        super().__init__()
        layer = nn.TransformerEncoderLayer(
            d_model=config.d_model,
            nhead=config.n_heads,
            dim_feedforward=config.ff_size,
            dropout=config.dropout,
            activation="gelu",
            batch_first=True,
        )
        self.encoder = nn.TransformerEncoder(layer, num_layers=config.msm_blocks + 1, enable_nested_tensor=False)

    def forward(self, d_in: Tensor, mask: Tensor) -> Tensor:
        return run_encoder(self.encoder, d_in, mask) * mask[..., None].to(d_in.dtype)


# ---- packing ----------------------------------------------------------------------------------------------------


def frame_aligned(content: Tensor, frames: int) -> Tensor:
    """Content tokens (B, Tc, d), zero at padding, cut or zero-padded to ``frames``: token i is content frame i."""
    if content.shape[1] >= frames:
        return content[:, :frames]
    return F.pad(content, (0, 0, 0, frames - content.shape[1]))


def pack(tokens: list[Tensor], masks: list[Tensor]) -> tuple[Tensor, Tensor, Tensor]:
    """Concatenate segments (B, L_i, d) along time keeping only real tokens, in order, padding at the end.

    Returns (packed (B, L, d), mask (B, L), position (B, sum L_i): where every input token went; padded input
    tokens land at or after the sample's real length). L is the longest sample's real token count.
    """
    x, m = torch.cat(tokens, dim=1), torch.cat(masks, dim=1)
    order = torch.argsort((~m).to(torch.uint8), dim=1, stable=True)  # real tokens first, original order kept
    position = torch.empty_like(order).scatter_(1, order, torch.arange(m.shape[1], device=m.device).expand_as(m))
    length = int(m.sum(dim=1).max())
    order = order[:, :length]
    packed = x.gather(1, order[..., None].expand(-1, -1, x.shape[-1]))
    return packed, m.gather(1, order), position


# ---- the network ------------------------------------------------------------------------------------------------


class UmsdNet(nn.Module):
    """UMSD: ``forward(x_t, t, content, content_mask, style, style_mask, x_mask) -> x0_hat`` (B, T, F).

    ``condition`` (UMSD attention, independent of x_t and t) and ``denoise`` (Eq. 6 + the denoiser) are the two
    halves, so a sampler computes the condition once.
    """

    def __init__(self, config: UmsdConfig | None = None) -> None:
        super().__init__()
        self.config = config = config or UmsdConfig()
        d = config.d_model
        self.register_buffer("pe", sinusoidal_table(config.max_len, d), persistent=False)  # positions
        self.register_buffer("time_pe", sinusoidal_table(NUM_TIMESTEPS, d), persistent=False)  # timesteps
        self.umsd_attention = UmsdAttention(config)
        self.x_in = nn.Linear(config.n_feats, d)  # the noisy motion m_t^z projected to tokens (Eq. 6)
        self.time_mlp = nn.Sequential(nn.Linear(d, d), nn.SiLU(), nn.Linear(d, d))  # Eq. 6: MLP(T)
        # Which part of Eq. 6 a token belongs to: each part's positions restart at 0, so the denoiser could not
        # otherwise tell a content frame from a noisy frame at the same position (not in the paper).
        self.segment = nn.Embedding(len(SEGMENTS), d)
        # Eq. 6 reaches content frame i from noisy frame i only through the token mixers (SSM scans over the whole
        # stream, one MHA); ``align_content`` adds a frame-to-frame path beside the concatenation (not in the paper).
        self.align = nn.Linear(d, d) if config.align_content else None
        self.dropout = nn.Dropout(config.dropout)
        self.denoiser: nn.Module = MsmDenoiser(config) if config.denoiser == "msm" else TransformerDenoiser(config)
        self.out = nn.Linear(d, config.n_feats)

    def condition(
        self, content: Tensor, content_mask: Tensor | None, style: Tensor, style_mask: Tensor | None
    ) -> UmsdCondition:
        """U(m_0^c, n_0^s) of Eqs. 10-11: UMSD attention over the clean content and style motions."""
        content_mask = self._mask(content, content_mask, "content")
        style_mask = self._mask(style, style_mask, "style")
        if content.shape[0] != style.shape[0]:
            raise MotionDataError("UmsdNet", f"content batch {content.shape[0]} != style batch {style.shape[0]}")
        return self.umsd_attention(content, content_mask, style, style_mask, self.pe.to(content.dtype))

    def denoise(self, x_t: Tensor, t: Tensor, cond: UmsdCondition, x_mask: Tensor | None = None) -> Tensor:
        """x_t (B, T, F), t (B,) training timesteps in [0, 1000), the condition -> x0_hat (B, T, F)."""
        x_mask = self._mask(x_t, x_mask, "x_t")
        batch, frames = x_mask.shape
        if t.shape != (batch,) or cond.content.shape[0] != batch:
            raise MotionDataError("UmsdNet", f"timesteps {tuple(t.shape)} / condition batch do not match ({batch},)")
        seg = self.segment.weight.to(x_t.dtype)
        x_tok = self.dropout(self.x_in(x_t) + self.pe[:frames].to(x_t.dtype)) + seg[0]
        if self.align is not None:
            x_tok = x_tok + self.align(frame_aligned(cond.content, frames))
        t_tok = self.time_mlp(self.time_pe[t.long().clamp(0, NUM_TIMESTEPS - 1)].to(x_t.dtype))[:, None] + seg[1]
        c_tok, s_tok = cond.content + seg[2], cond.style + seg[3]
        one = torch.ones(batch, 1, dtype=torch.bool, device=x_t.device)
        # Eq. 6: D_in = concat(m_t^z, MLP(T), Z^out), along time, packed
        d_in, mask, position = pack([x_tok, t_tok, c_tok, s_tok], [x_mask, one, cond.content_mask, cond.style_mask])
        h = self.denoiser(d_in, mask)
        where = position[:, :frames].clamp(max=h.shape[1] - 1)  # the noisy frames' tokens (padding: any, zeroed)
        h = h.gather(1, where[..., None].expand(-1, -1, h.shape[-1]))
        return self.out(h) * x_mask[..., None].to(h.dtype)

    def forward(
        self,
        x_t: Tensor,
        t: Tensor,
        content: Tensor,
        content_mask: Tensor | None,
        style: Tensor,
        style_mask: Tensor | None,
        x_mask: Tensor | None = None,
    ) -> Tensor:
        """x_t (B, T, F) noisy motion, t (B,), content (B, Tc, F), style (B, Ts, F), masks True = real frame."""
        return self.denoise(x_t, t, self.condition(content, content_mask, style, style_mask), x_mask)

    def _mask(self, x: Tensor, mask: Tensor | None, name: str) -> Tensor:
        if x.ndim != 3 or x.shape[-1] != self.config.n_feats:
            raise MotionDataError("UmsdNet", f"{name} must be (B, T, {self.config.n_feats}), got {tuple(x.shape)}")
        if x.shape[1] > self.config.max_len:
            raise MotionDataError("UmsdNet", f"{name}: {x.shape[1]} frames exceed max_len {self.config.max_len}")
        if mask is None:
            return torch.ones(x.shape[:2], dtype=torch.bool, device=x.device)
        if mask.shape != x.shape[:2]:
            raise MotionDataError("UmsdNet", f"{name} mask {tuple(mask.shape)} != {tuple(x.shape[:2])}")
        mask = mask.bool()
        if not bool(mask.any(dim=1).all()):
            raise MotionDataError("UmsdNet", f"{name}: a sample has no real frame")
        return mask
