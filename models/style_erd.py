"""Style-ERD (Tao et al., CVPR 2022): online, frame-by-frame motion style transfer, plus its two critics.

One frame in, one frame out. Sections refer to "Style-ERD: Responsive and Coherent Online Motion Style Transfer"
("supp. A": its implementation appendix). The generator ``ErdNetwork`` is ``Encoder`` -> ``Recurrent`` (a neutral
LSTM branch plus one residual branch per style, sec. 3.1 and 4.4) -> ``Decoder``; ``forward`` runs whole sequences
and ``step`` one frame, and the two agree to float rounding. The critics are ``FtAttDiscriminator`` (Eq. 1) and
``ContentClassifier`` (the perceptual loss's phi, Eq. 7), with an optional ``StyleClassifier``. Frames are HumanML3D
features normalised by the corpus Mean/Std the network carries as buffers; style index 0 is always ``neutral``, and
content index ``len(contents)`` is the learned "unknown content" slot for unlabelled input.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any, NamedTuple

import torch
import torch.nn.functional as F
from torch import Tensor, nn

NEUTRAL = "neutral"
UNKNOWN_CONTENT = "<unknown>"


@dataclass(frozen=True)
class StyleErdConfig:
    """Sizes of the Style-ERD generator and its critics. Defaults follow supp. A where it gives a number."""

    styles: tuple[str, ...] = (NEUTRAL,)  # index 0 must be neutral: it is the basis branch r_0 (sec. 3.1)
    contents: tuple[str, ...] = ()  # known content labels; one more slot is the learned "unknown content"
    n_joints: int = 22  # HumanML3D t2m rig: 4 + 9 (J - 1) + 3 J + 4 = 263 channels
    enc_hidden: int = 64  # supp. A: encoder MLP (64, 32)
    latent: int = 32  # supp. A: z is 32-d; also every LSTM's hidden size, so r_0 and r_S outputs add
    neutral_layers: int = 6  # supp. A: 6 LSTM layers in r_0
    style_layers: int = 4  # supp. A: 4 LSTM layers in each style branch
    dec_hidden: tuple[int, ...] = (64, 128, 256)  # three hidden + the output layer = the four MLP layers of sec. 3.1
    # Discriminator window: the paper's T = 24 frames at 60 fps is 0.4 s. Style shows in timing (tempo, bounce,
    # hesitation), so the critic must see the same *duration* of motion, not the same frame count: 0.4 s is
    # 8 frames at HumanML3D's 20 fps (24 frames would be 1.2 s, three times the context the paper validated).
    disc_window: int = 8
    disc_channels: tuple[int, int] = (96, 64)  # conv widths; the last one is C' of Eq. 1
    cls_channels: tuple[int, int] = (96, 64)  # the content classifier "follows the same convolution layers"
    kernel: int = 3
    att_hidden: int = 64  # MLP width of the attention branches
    # Output skip: x'_t = x_t + D(z'_t, S_hat). Not in the paper (its decoder emits the frame itself). At a CPU
    # budget of a few thousand steps the 32-d bottleneck and six stacked LSTMs are far from reconstructing a
    # frame, so the transfer has no content to keep. With the skip, E -> R -> D
    # only learns the style *offset* of each frame: the paper's residual idea (z' = r_0 + r_S) at the output.
    residual_output: bool = True
    attention: bool = True  # FT-Att (Eq. 1); False: Table 1's "w/o attention", a multi-class critic
    learned_init: bool = True  # learned initial states (sec. 3.1); False: zero states (Table 1 ablation)

    def __post_init__(self) -> None:
        object.__setattr__(self, "styles", tuple(self.styles))
        object.__setattr__(self, "contents", tuple(self.contents))
        object.__setattr__(self, "dec_hidden", tuple(self.dec_hidden))
        object.__setattr__(self, "disc_channels", tuple(self.disc_channels))
        object.__setattr__(self, "cls_channels", tuple(self.cls_channels))
        if not self.styles or self.styles[0] != NEUTRAL:
            raise ValueError(f"styles must start with {NEUTRAL!r} (branch r_0), got {list(self.styles)}")
        if len(set(self.styles)) != len(self.styles) or len(set(self.contents)) != len(self.contents):
            raise ValueError("style and content names must be unique")
        if UNKNOWN_CONTENT in self.contents:
            raise ValueError(f"{UNKNOWN_CONTENT!r} is reserved for the unknown-content slot")
        if not 1 <= self.style_layers <= self.neutral_layers:
            raise ValueError(f"need 1 <= style_layers <= neutral_layers, got {self.style_layers}/{self.neutral_layers}")
        if min(self.latent, self.enc_hidden, self.disc_window, self.kernel, self.n_joints) < 1:
            raise ValueError("sizes must be positive")
        if self.kernel % 2 == 0:
            raise ValueError(f"kernel must be odd (same-length convs), got {self.kernel}")

    @property
    def frame_dim(self) -> int:
        return 4 + 9 * (self.n_joints - 1) + 3 * self.n_joints + 4

    @property
    def n_styles(self) -> int:
        return len(self.styles)

    @property
    def n_branches(self) -> int:
        """Residual style branches r_1..r_nS (every style but neutral)."""
        return len(self.styles) - 1

    @property
    def n_contents(self) -> int:
        """Content one-hot width: the known labels plus the unknown slot (last)."""
        return len(self.contents) + 1

    @property
    def unknown_content(self) -> int:
        return len(self.contents)

    def to_dict(self) -> dict[str, Any]:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> StyleErdConfig:
        known = cls.__dataclass_fields__
        unknown = sorted(set(data) - set(known))
        if unknown:
            raise ValueError(f"unknown StyleErdConfig fields {unknown}")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in data.items()})


def frame_slices(n_joints: int = 22) -> dict[str, slice]:
    """HumanML3D channel blocks (same layout as ``motionaug.augment.motion.features.feature_slices``)."""
    j = n_joints
    widths = {
        "root_rot_vel": 1,
        "root_lin_vel": 2,
        "root_y": 1,
        "ric": 3 * (j - 1),
        "rot": 6 * (j - 1),
        "local_vel": 3 * j,
        "feet": 4,
    }
    out, start = {}, 0
    for name, width in widths.items():
        out[name] = slice(start, start + width)
        start += width
    return out


def channel_groups(n_joints: int = 22) -> dict[str, list[int]]:
    """The paper's frame parts (sec. 3.1) mapped onto HumanML3D channels.

    ``rot``: joint rotations (6D here, quaternions in the paper); ``pos``: positions offset by the root
    (root height + ric); ``vel``: velocities (root yaw/xz velocity + local joint velocities); ``feet``: foot
    contacts, which the paper's frames do not have.
    """
    s = frame_slices(n_joints)

    def rng(*names: str) -> list[int]:
        return [i for n in names for i in range(s[n].start, s[n].stop)]

    return {
        "rot": rng("rot"),
        "pos": rng("root_y", "ric"),
        "vel": rng("root_rot_vel", "root_lin_vel", "local_vel"),
        "feet": rng("feet"),
    }


# ---- generator ------------------------------------------------------------------------------------------


class Encoder(nn.Module):
    """E (sec. 3.1): ``[x_t, S, C] -> z_t``, two layers (64, 32) as supp. A.

    ReLU after the hidden layer only: the 32-d latent feeds LSTMs and stays linear so no bottleneck unit can die.
    """

    def __init__(self, cfg: StyleErdConfig) -> None:
        super().__init__()
        self.fc1 = nn.Linear(cfg.frame_dim + cfg.n_styles + cfg.n_contents, cfg.enc_hidden)
        self.fc2 = nn.Linear(cfg.enc_hidden, cfg.latent)

    def forward(self, x: Tensor, cond: Tensor) -> Tensor:
        # F.linear on the weights, not the submodules: a module call costs as much as the matmul at batch 1
        h = F.relu(F.linear(torch.cat([x, cond], dim=-1), self.fc1.weight, self.fc1.bias))
        return F.linear(h, self.fc2.weight, self.fc2.bias)


class ErdState(NamedTuple):
    """Recurrent state of every branch, batch ``B``.

    ``h``/``c`` (style_layers, 1 + n_branches, B, H): layers shared by all branches (index 0 = r_0);
    ``h_top``/``c_top`` (neutral_layers - style_layers, B, H): r_0's extra layers.
    """

    h: Tensor
    c: Tensor
    h_top: Tensor
    c_top: Tensor

    def select(self, index: Tensor) -> ErdState:
        """The state of batch rows ``index``."""
        return ErdState(self.h[:, :, index], self.c[:, :, index], self.h_top[:, index], self.c_top[:, index])


class Recurrent(nn.Module):
    """R = [r_0, r_1, ..., r_nS] (sec. 3.1): ``z'_t = r_0(z_t) + sum_S a_S r_S(z_t)``.

    ``a`` is the one-hot target style for plain transfer, ``(alpha, 1 - alpha)`` on two styles for blending
    and ``alpha`` on one style for intensity (sec. 4.4). Layers ``0..style_layers-1`` of every branch are
    stored stacked, ``(layers, 1 + n_branches, 4H, H)``, so ``step`` advances all branches with one batched
    matmul per layer; r_0's remaining layers live in ``top_*``. Gate order i, f, g, o as ``nn.LSTM``; one bias
    per layer (``nn.LSTM``'s b_ih + b_hh folded into one).
    """

    def __init__(self, cfg: StyleErdConfig) -> None:
        super().__init__()
        h, ls, n_top, nb = cfg.latent, cfg.style_layers, cfg.neutral_layers - cfg.style_layers, cfg.n_branches
        self.cfg = cfg
        self.w_ih = nn.Parameter(torch.empty(ls, nb + 1, 4 * h, h))
        self.w_hh = nn.Parameter(torch.empty(ls, nb + 1, 4 * h, h))
        self.bias = nn.Parameter(torch.empty(ls, nb + 1, 4 * h))
        self.top_w_ih = nn.Parameter(torch.empty(n_top, 4 * h, h))
        self.top_w_hh = nn.Parameter(torch.empty(n_top, 4 * h, h))
        self.top_bias = nn.Parameter(torch.empty(n_top, 4 * h))
        # Learned initial states (sec. 3.1): r_0 learns one per content label (+ the unknown slot),
        # each style branch learns its own.
        self.h0_neutral = nn.Parameter(torch.zeros(cfg.neutral_layers, cfg.n_contents, h))
        self.c0_neutral = nn.Parameter(torch.zeros(cfg.neutral_layers, cfg.n_contents, h))
        self.h0_style = nn.Parameter(torch.zeros(ls, nb, h))
        self.c0_style = nn.Parameter(torch.zeros(ls, nb, h))
        if not cfg.learned_init:  # Table 1 "w/o learnt initial states": zero states, as [31]
            for p in (self.h0_neutral, self.c0_neutral, self.h0_style, self.c0_style):
                p.requires_grad_(False)
        self.register_buffer("zero_bias", torch.zeros(4 * h), persistent=False)
        self.reset_parameters()

    def reset_parameters(self) -> None:
        """PyTorch's LSTM default, U(-1/sqrt(H), 1/sqrt(H)) (supp. A keeps the defaults); initial states zero."""
        bound = 1.0 / math.sqrt(self.cfg.latent)
        for p in (self.w_ih, self.w_hh, self.bias, self.top_w_ih, self.top_w_hh, self.top_bias):
            nn.init.uniform_(p, -bound, bound)

    def initial_state(self, content: Tensor) -> ErdState:
        """Learned initial state for content weights ``content`` (B, n_contents) (one-hot picks one)."""
        cfg = self.cfg
        ls, batch = cfg.style_layers, content.shape[0]
        h_n = torch.einsum("lch,bc->lbh", self.h0_neutral, content)
        c_n = torch.einsum("lch,bc->lbh", self.c0_neutral, content)
        shape = (ls, cfg.n_branches, batch, cfg.latent)
        h_s = self.h0_style[:, :, None, :].expand(shape)
        c_s = self.c0_style[:, :, None, :].expand(shape)
        h = torch.cat([h_n[:ls, None], h_s], dim=1)
        c = torch.cat([c_n[:ls, None], c_s], dim=1)
        return ErdState(h, c, h_n[ls:], c_n[ls:])

    def _branch_params(self, branch: int) -> list[Tensor]:
        params: list[Tensor] = []
        for layer in range(self.cfg.style_layers):
            params += [self.w_ih[layer, branch], self.w_hh[layer, branch], self.bias[layer, branch], self.zero_bias]
        if branch == 0:
            for layer in range(self.cfg.neutral_layers - self.cfg.style_layers):
                params += [self.top_w_ih[layer], self.top_w_hh[layer], self.top_bias[layer], self.zero_bias]
        return params

    def _run(self, branch: int, z: Tensor, h0: Tensor, c0: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """One branch over a whole sequence in one C++ call (``torch.lstm``, what ``nn.LSTM`` runs)."""
        params = self._branch_params(branch)
        layers = len(params) // 4
        out, h, c = torch.lstm(z, (h0.contiguous(), c0.contiguous()), params, True, layers, 0.0, False, False, True)
        return out, h, c

    def forward(self, z: Tensor, state: ErdState, coef: Tensor, skip_idle: bool = False) -> tuple[Tensor, ErdState]:
        """Whole sequences: ``z`` (B, T, H), ``coef`` (B, T, n_branches) residual weights -> (B, T, H), state.

        ``skip_idle`` runs a style branch only for rows where it has a non-zero weight at some frame (training,
        offline transfer); the returned state of the skipped (branch, row) pairs is then the input state, so
        pass ``skip_idle=False`` when the state will be carried on (streaming continuation).
        """
        ls = self.cfg.style_layers
        h0 = torch.cat([state.h[:, 0], state.h_top], dim=0)
        c0 = torch.cat([state.c[:, 0], state.c_top], dim=0)
        out, h_n, c_n = self._run(0, z, h0, c0)
        hs, cs = [h_n[:ls]], [c_n[:ls]]
        for b in range(self.cfg.n_branches):
            weight = coef[..., b : b + 1]
            rows = None
            if skip_idle:
                active = (weight != 0).flatten(1).any(dim=1)
                if not bool(active.any()):
                    hs.append(state.h[:, b + 1])
                    cs.append(state.c[:, b + 1])
                    continue
                if not bool(active.all()):
                    rows = active.nonzero().squeeze(1)
            if rows is None:
                out_b, h_b, c_b = self._run(b + 1, z, state.h[:, b + 1], state.c[:, b + 1])
                out = out + weight * out_b
            else:
                out_b, h_b, c_b = self._run(b + 1, z[rows], state.h[:, b + 1, rows], state.c[:, b + 1, rows])
                out = out.index_add(0, rows, weight[rows] * out_b)
                h_b = state.h[:, b + 1].index_copy(1, rows, h_b)
                c_b = state.c[:, b + 1].index_copy(1, rows, c_b)
            hs.append(h_b)
            cs.append(c_b)
        new = ErdState(torch.stack(hs, dim=1), torch.stack(cs, dim=1), h_n[ls:], c_n[ls:])
        return out, new

    def step(self, z: Tensor, state: ErdState, coef: Tensor) -> tuple[Tensor, ErdState]:
        """One frame: ``z`` (B, H), ``coef`` (B, n_branches) -> (B, H), state. Every branch advances."""
        h = self.cfg.latent
        # layer 0 reads the same z_t in every branch: one matmul for all of them
        gates0 = F.linear(z, self.w_ih[0].reshape(-1, h)).view(z.shape[0], -1, 4 * h).transpose(0, 1)
        x = z
        hs, cs = [], []
        for layer in range(self.cfg.style_layers):
            bias = self.bias[layer].unsqueeze(1)
            if layer == 0:
                gates = torch.baddbmm(gates0 + bias, state.h[0], self.w_hh[0].transpose(1, 2))
            else:
                gates = torch.baddbmm(bias, x, self.w_ih[layer].transpose(1, 2))
                gates = torch.baddbmm(gates, state.h[layer], self.w_hh[layer].transpose(1, 2))
            i_f = torch.sigmoid(gates[..., : 2 * h])
            g = torch.tanh(gates[..., 2 * h : 3 * h])
            o = torch.sigmoid(gates[..., 3 * h :])
            c = torch.addcmul(i_f[..., h:] * state.c[layer], i_f[..., :h], g)
            x = o * torch.tanh(c)
            hs.append(x)
            cs.append(c)
        y = x[0]
        h_top, c_top = [], []
        for layer in range(self.cfg.neutral_layers - self.cfg.style_layers):
            y, c = torch.lstm_cell(
                y,
                (state.h_top[layer], state.c_top[layer]),
                self.top_w_ih[layer],
                self.top_w_hh[layer],
                self.top_bias[layer],
                self.zero_bias,
            )
            h_top.append(y)
            c_top.append(c)
        if self.cfg.n_branches:
            # sum_S a_S r_S(z_t): (B, 1, nb) @ (B, nb, H)
            y = y + torch.bmm(coef.unsqueeze(1), x[1:].transpose(0, 1)).squeeze(1)
        top = (torch.stack(h_top), torch.stack(c_top)) if h_top else (state.h_top, state.c_top)
        return y, ErdState(torch.stack(hs), torch.stack(cs), *top)


class Decoder(nn.Module):
    """D (sec. 3.1): ``[z'_t, S_hat] -> x'_t`` through four MLP layers with ReLU, conditioned on the target style.

    With ``residual_output``: ``[z'_t, S_hat, S, C] -> x'_t - x_t``, the last layer zero at initialisation.

    The paper decodes rotations + velocities and gets positions by FK; HumanML3D frames carry positions
    (``ric``) themselves, so the decoder emits the whole 263-d frame.
    """

    def __init__(self, cfg: StyleErdConfig) -> None:
        super().__init__()
        # With the output skip the offset depends on where the frame comes from as much as where it goes
        # (S -> S is zero, neutral -> S is not) and on the content (an elderly walk and an elderly wave move
        # differently from their neutral versions), so the decoder also sees the encoder's [source, content].
        self.with_source = cfg.residual_output
        extra = cfg.n_styles + cfg.n_contents if self.with_source else 0
        sizes = [cfg.latent + cfg.n_styles + extra, *cfg.dec_hidden, cfg.frame_dim]
        self.layers = nn.ModuleList(nn.Linear(a, b) for a, b in zip(sizes[:-1], sizes[1:]))
        if cfg.residual_output:  # start as the identity: the offset D(z', S_hat) is zero until trained
            nn.init.zeros_(self.layers[-1].weight)
            nn.init.zeros_(self.layers[-1].bias)

    def forward(self, z: Tensor, target: Tensor, source: Tensor | None = None) -> Tensor:
        parts = [z, target, source] if self.with_source and source is not None else [z, target]
        x = torch.cat(parts, dim=-1)
        last = len(self.layers) - 1
        for i, layer in enumerate(self.layers):
            x = F.linear(x, layer.weight, layer.bias)
            if i < last:
                x = F.relu(x)
        return x


class ErdNetwork(nn.Module):
    """The Style-ERD generator E -> R -> D with the corpus normaliser as buffers.

    Conditioning tensors (float, so one-hots and mixtures share one path):

    - ``source`` (B, n_styles): style of the input frames (one-hot; neutral = index 0).
    - ``content`` (B, n_contents): content label one-hot, last slot = unknown content.
    - ``target`` (B, n_styles) or (B, T, n_styles): target-style mixture ``w`` (non-negative, sums to 1).
      The decoder is conditioned on ``w``; the residual weights are ``w[1:]`` (sec. 4.4). One-hot = plain
      transfer; ``alpha e_S + (1 - alpha) e_neutral`` = intensity alpha; ``alpha e_S + (1 - alpha) e_S'`` = blend.
    """

    def __init__(self, config: StyleErdConfig) -> None:
        super().__init__()
        self.config = config
        self.encoder = Encoder(config)
        self.recurrent = Recurrent(config)
        self.decoder = Decoder(config)
        self.register_buffer("mean", torch.zeros(config.frame_dim))
        self.register_buffer("std", torch.ones(config.frame_dim))

    # -- labels -> conditioning vectors --

    def style_index(self, name: str) -> int:
        try:
            return self.config.styles.index(name)
        except ValueError:
            raise KeyError(name) from None

    def content_index(self, name: str | None) -> int:
        if name is None:
            return self.config.unknown_content
        try:
            return self.config.contents.index(name)
        except ValueError:
            raise KeyError(name) from None

    def style_onehot(self, index: Tensor) -> Tensor:
        return F.one_hot(index, self.config.n_styles).to(self.mean.dtype)

    def content_onehot(self, index: Tensor) -> Tensor:
        return F.one_hot(index, self.config.n_contents).to(self.mean.dtype)

    def mixture(self, style: str, intensity: float = 1.0, blend_with: str | None = None, alpha: float = 1.0) -> Tensor:
        """Target mixture (n_styles,), sec. 4.4: ``i * (a e_style + (1 - a) e_blend) + (1 - i) e_neutral``.

        ``i`` = intensity, ``a`` = alpha; ``blend_with`` None blends the style with itself (pure style).
        """
        w = torch.zeros(self.config.n_styles, dtype=self.mean.dtype, device=self.mean.device)
        w[self.style_index(style)] += intensity * alpha
        w[self.style_index(blend_with if blend_with is not None else style)] += intensity * (1.0 - alpha)
        w[0] += 1.0 - intensity
        return w

    # -- normaliser --

    def set_normalizer(self, mean: Tensor, std: Tensor) -> None:
        self.mean.copy_(torch.as_tensor(mean, dtype=self.mean.dtype))
        self.std.copy_(torch.as_tensor(std, dtype=self.std.dtype))

    def normalize(self, x: Tensor) -> Tensor:
        return (x - self.mean) / self.std

    def denormalize(self, x: Tensor) -> Tensor:
        return x * self.std + self.mean

    # -- a style added after training --

    def with_style(self, name: str) -> ErdNetwork:
        """A copy with one more style, last: a new residual branch r_S beside the trained ones (sec. 3.1).

        The paper trains every branch jointly; a style added later gets its branch fitted alone
        (``augment/methods/erd/branch.py``). Its branch, initial states and the decoder's target column start as
        the mean of the trained styles', so the fit starts from "some style", not from noise; the encoder's and
        decoder's source columns for it are zero, since a new style is only ever a target.
        """
        cfg = self.config
        if name in cfg.styles:
            raise ValueError(f"style {name!r} is already in the network")
        if not cfg.n_branches:
            raise ValueError("a network without trained style branches has no style to start a new one from")
        grown = ErdNetwork(replace(cfg, styles=(*cfg.styles, name)))
        state = self.state_dict()
        n_s, dim, latent = cfg.n_styles, cfg.frame_dim, cfg.latent
        for key in ("w_ih", "w_hh", "bias"):
            stacked = state[f"recurrent.{key}"]
            state[f"recurrent.{key}"] = torch.cat([stacked, stacked[:, 1:].mean(1, keepdim=True)], 1)
        for key in ("h0_style", "c0_style"):
            init = state[f"recurrent.{key}"]
            state[f"recurrent.{key}"] = torch.cat([init, init.mean(1, keepdim=True)], 1)
        w = state["encoder.fc1.weight"]
        zero = torch.zeros_like(w[:, :1])
        state["encoder.fc1.weight"] = torch.cat([w[:, : dim + n_s], zero, w[:, dim + n_s :]], 1)
        w = state["decoder.layers.0.weight"]
        target = w[:, latent : latent + n_s]
        zero = torch.zeros_like(w[:, :1])
        parts = [w[:, :latent], target, target[:, 1:].mean(1, keepdim=True)]
        if self.decoder.with_source:
            parts += [w[:, latent + n_s : latent + 2 * n_s], zero, w[:, latent + 2 * n_s :]]
        state["decoder.layers.0.weight"] = torch.cat(parts, 1)
        grown.load_state_dict(state, strict=True)
        return grown.train(self.training)

    # -- forward --

    def initial_state(self, content: Tensor) -> ErdState:
        return self.recurrent.initial_state(content)

    def forward(
        self,
        x: Tensor,
        source: Tensor,
        content: Tensor,
        target: Tensor,
        state: ErdState | None = None,
        skip_idle: bool = False,
    ) -> tuple[Tensor, ErdState]:
        """Whole sequences ``x`` (B, T, D) normalised -> (B, T, D) normalised, and the state after frame T-1."""
        batch, frames = x.shape[:2]
        if state is None:
            state = self.initial_state(content)
        cond = torch.cat([source, content], dim=-1)[:, None].expand(batch, frames, -1)
        z = self.encoder(x, cond)
        if target.dim() == 2:
            target = target[:, None].expand(batch, frames, -1)
        z, state = self.recurrent(z, state, target[..., 1:], skip_idle=skip_idle)
        y = self.decoder(z, target, cond)
        return (x + y if self.config.residual_output else y), state

    def step(
        self, x: Tensor, state: ErdState, source: Tensor, content: Tensor, target: Tensor
    ) -> tuple[Tensor, ErdState]:
        """One frame ``x`` (B, D) normalised -> (B, D) normalised, and the next state."""
        cond = torch.cat([source, content], dim=-1)
        z = self.encoder(x, cond)
        z, state = self.recurrent.step(z, state, target[:, 1:])
        y = self.decoder(z, target, cond)
        return (x + y if self.config.residual_output else y), state


# ---- critics --------------------------------------------------------------------------------------------


class FtAttDiscriminator(nn.Module):
    """FT-Att discriminator D_S (sec. 3.1, Fig. 3, Eq. 1) on windows of ``disc_window`` frames.

    Input: root-relative positions and velocities of the window (the paper follows Aberman et al.: positions
    say more about style than rotations). 1-D temporal convs give ``m_s`` (C', T'); MLPs of the
    [style, content] labels give feature attention ``w_f`` (C') and temporal attention ``w_t`` (T');
    ``D = sum_ij (m_s o (w_f (x) w_t))_ij``. LeakyReLU as supp. A; the last conv is linear so the sum can take
    either sign (the LSGAN targets are -1 / +1, Eq. 5); attention vectors are sigmoids (weights in (0, 1)).
    """

    def __init__(self, cfg: StyleErdConfig) -> None:
        super().__init__()
        groups = channel_groups(cfg.n_joints)
        self.register_buffer("channels", torch.tensor(groups["pos"] + groups["vel"]), persistent=False)
        c1, c2 = cfg.disc_channels
        pad = cfg.kernel // 2
        self.window = cfg.disc_window
        self.conv = nn.Sequential(
            nn.Conv1d(len(groups["pos"]) + len(groups["vel"]), c1, cfg.kernel, padding=pad),
            nn.LeakyReLU(0.2),
            nn.Conv1d(c1, c2, cfg.kernel, padding=pad),
        )
        cond = cfg.n_styles + cfg.n_contents
        self.feature_att = nn.Sequential(
            nn.Linear(cond, cfg.att_hidden), nn.LeakyReLU(0.2), nn.Linear(cfg.att_hidden, c2)
        )
        self.temporal_att = nn.Sequential(
            nn.Linear(cond, cfg.att_hidden), nn.LeakyReLU(0.2), nn.Linear(cfg.att_hidden, cfg.disc_window)
        )
        # w/o attention (Table 1): the baseline of [1, 32], a shared conv trunk with one output head per style
        self.style_heads = None if cfg.attention else nn.Linear(c2, cfg.n_styles)

    def with_style(self, grown: StyleErdConfig) -> FtAttDiscriminator:
        """A copy for ``grown`` (``ErdNetwork.with_style``'s config): the new style's attention columns, or its
        head, start as the mean of the trained styles'."""
        n_s = grown.n_styles - 1
        critic = FtAttDiscriminator(grown)
        state = self.state_dict()
        for key in ("feature_att.0.weight", "temporal_att.0.weight"):
            w = state[key]
            state[key] = torch.cat([w[:, :n_s], w[:, 1:n_s].mean(1, keepdim=True), w[:, n_s:]], 1)
        for key in ("style_heads.weight", "style_heads.bias"):
            if key in state:
                state[key] = torch.cat([state[key], state[key][1:].mean(0, keepdim=True)], 0)
        critic.load_state_dict(state, strict=True)
        return critic

    def forward(self, x: Tensor, style: Tensor, content: Tensor) -> Tensor:
        """``x`` (B, disc_window, D) normalised frames; ``style`` (B, n_styles); ``content`` (B, n_contents) -> (B,)."""
        if x.shape[1] != self.window:
            raise ValueError(f"discriminator window is {self.window} frames, got {x.shape[1]}")
        m = self.conv(x[..., self.channels].transpose(1, 2))  # m_s: (B, C', T')
        if self.style_heads is not None:  # multi-class discriminator: the target style's head, averaged over time
            return (self.style_heads(m.mean(dim=-1)) * style).sum(dim=-1)
        cond = torch.cat([style, content], dim=-1)
        w_f = torch.sigmoid(self.feature_att(cond))
        w_t = torch.sigmoid(self.temporal_att(cond))
        w_s = w_f[:, :, None] * w_t[:, None, :]  # outer product w_f (x) w_t
        return (m * w_s).sum(dim=(1, 2))  # Eq. 1: Hadamard product, summed


class ContentClassifier(nn.Module):
    """D_C (sec. 3.1): content classification from rotations, positions and velocities (the whole frame).

    Conv -> InstanceNorm -> LeakyReLU twice: IN removes each channel's per-clip mean and scale, much of what a
    style changes, so the features (``phi``, the perceptual loss's feature maps, Eq. 7) track content.
    """

    def __init__(self, cfg: StyleErdConfig) -> None:
        super().__init__()
        c1, c2 = cfg.cls_channels
        pad = cfg.kernel // 2
        self.body = nn.Sequential(
            nn.Conv1d(cfg.frame_dim, c1, cfg.kernel, padding=pad),
            nn.InstanceNorm1d(c1),
            nn.LeakyReLU(0.2),
            nn.Conv1d(c1, c2, cfg.kernel, padding=pad),
            nn.InstanceNorm1d(c2),
            nn.LeakyReLU(0.2),
        )
        self.head = nn.Linear(c2, max(len(cfg.contents), 1))

    def features(self, x: Tensor) -> Tensor:
        """phi: (B, T, D) normalised frames -> (B, C, T) feature maps."""
        return self.body(x.transpose(1, 2))

    def forward(self, x: Tensor) -> Tensor:
        """Content logits (B, len(contents))."""
        return self.head(self.features(x).mean(dim=-1))


class StyleClassifier(nn.Module):
    """Style supervision (not in the paper): a style classifier on root-relative positions and velocities.

    Trained before the GAN stage on real windows and then frozen, like D_C; the generator gets its
    cross-entropy against the target style. No instance norm: the per-clip channel means and scales it would
    remove are much of what a style is (posture, amplitude, speed).
    """

    def __init__(self, cfg: StyleErdConfig) -> None:
        super().__init__()
        groups = channel_groups(cfg.n_joints)
        self.register_buffer("channels", torch.tensor(groups["pos"] + groups["vel"]), persistent=False)
        c1, c2 = cfg.cls_channels
        pad = cfg.kernel // 2
        self.body = nn.Sequential(
            nn.Conv1d(len(groups["pos"]) + len(groups["vel"]), c1, cfg.kernel, padding=pad),
            nn.LeakyReLU(0.2),
            nn.Conv1d(c1, c2, cfg.kernel, padding=pad),
            nn.LeakyReLU(0.2),
        )
        self.head = nn.Linear(c2, cfg.n_styles)

    def forward(self, x: Tensor) -> Tensor:
        """(B, T, D) normalised frames -> style logits (B, n_styles)."""
        return self.head(self.body(x[..., self.channels].transpose(1, 2)).mean(dim=-1))
