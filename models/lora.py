"""Low-rank adapters (LoRA, Hu et al. 2022) so a per-style fine-tune ships a few percent of the model's bytes.

Every adapted weight reads as ``W + (alpha / rank) * B @ A``, ``B`` zero at start so the adapted model equals the
base. Two mechanisms, because ``nn.MultiheadAttention`` and the encoder layer's fast path read weights directly
instead of calling ``forward``: ``nn.Linear`` targets become ``LoRALinear``, whose ``weight``/``bias`` properties
expose the effective weight to such code, and ``in_proj_weight`` gets a parametrization (``LoRAInProj``) with one
adapter per q/k/v block, seen by both attention paths. ``apply_lora`` freezes everything else; ``merge_lora`` folds
the deltas back and restores the plain modules (and the base state-dict keys) for inference.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Mapping

import torch
import torch.nn.functional as F
from torch import Tensor, nn
from torch.nn.utils import parametrize

from motionaug.schemas.errors import MotionDataError

LORA_PREFIX = "lora_"  # every adapter tensor's own name starts with this
DEFAULT_TARGETS = ("self_attn", "linear1", "linear2")
_IN_PROJ = "in_proj_weight"


def _check_hyper(rank: int, alpha: float, dropout: float, fan_in: int, fan_out: int, what: str) -> None:
    if not 1 <= rank <= min(fan_in, fan_out):
        raise MotionDataError(what, f"LoRA rank {rank} outside [1, {min(fan_in, fan_out)}]")
    if not alpha > 0:
        raise MotionDataError(what, f"LoRA alpha {alpha} must be positive")
    if not 0.0 <= dropout < 1.0:
        raise MotionDataError(what, f"LoRA dropout {dropout} outside [0, 1)")


def _init_pair(a: Tensor, b: Tensor, generator: torch.Generator | None = None) -> None:
    """A like nn.Linear's default init (so the path has signal), B zero (so the delta starts at zero).

    A is drawn where ``generator`` lives (a CPU generator draws on CPU, then copies): same seed, same A anywhere.
    """
    if generator is not None and generator.device != a.device:
        drawn = torch.empty(a.shape, dtype=a.dtype, device=generator.device)
        nn.init.kaiming_uniform_(drawn, a=math.sqrt(5), generator=generator)
        with torch.no_grad():
            a.copy_(drawn)
    else:
        nn.init.kaiming_uniform_(a, a=math.sqrt(5), generator=generator)
    nn.init.zeros_(b)


class LoRALinear(nn.Module):
    """A frozen ``nn.Linear`` plus a trainable low-rank path: ``y = base(x) + s * B(A(dropout(x)))``.

    ``weight``/``bias`` give the effective (merged) parameters for callers that read weights instead
    of calling the module; dropout acts only on the ``forward`` path (it is inactive in eval anyway).
    """

    def __init__(
        self,
        base: nn.Linear,
        rank: int = 8,
        alpha: float = 16.0,
        dropout: float = 0.0,
        generator: torch.Generator | None = None,
    ) -> None:
        super().__init__()
        _check_hyper(rank, alpha, dropout, base.in_features, base.out_features, "LoRALinear")
        base.requires_grad_(False)
        self.base = base
        kw = {"dtype": base.weight.dtype, "device": base.weight.device}
        self.lora_A = nn.Parameter(torch.empty(rank, base.in_features, **kw))
        self.lora_B = nn.Parameter(torch.empty(base.out_features, rank, **kw))
        self.register_buffer("lora_scale", torch.tensor(alpha / rank, **kw))
        self.dropout = nn.Dropout(dropout)
        _init_pair(self.lora_A, self.lora_B, generator)

    @property
    def in_features(self) -> int:
        return self.base.in_features

    @property
    def out_features(self) -> int:
        return self.base.out_features

    @property
    def weight(self) -> Tensor:
        return self.base.weight + self.delta_weight()

    @property
    def bias(self) -> Tensor | None:
        return self.base.bias

    def delta_weight(self) -> Tensor:
        """(out, in) low-rank update ``s * B @ A``."""
        return self.lora_scale * (self.lora_B @ self.lora_A)

    def forward(self, x: Tensor) -> Tensor:
        low = F.linear(F.linear(self.dropout(x), self.lora_A), self.lora_B)  # (..., out) via (..., rank)
        return self.base(x) + self.lora_scale * low

    def merged(self) -> nn.Linear:
        """A plain ``nn.Linear`` with the delta folded in (frozen like the base)."""
        out = nn.Linear(self.in_features, self.out_features, bias=self.base.bias is not None)
        out = out.to(dtype=self.base.weight.dtype, device=self.base.weight.device)
        with torch.no_grad():
            out.weight.copy_(self.weight)
            if self.base.bias is not None:
                out.bias.copy_(self.base.bias)
        return out.requires_grad_(False)


class LoRAInProj(nn.Module):
    """Parametrization of MHA's packed (3E, E) ``in_proj_weight``: one rank-r adapter per q, k, v block."""

    def __init__(
        self, embed_dim: int, rank: int, alpha: float, like: Tensor, generator: torch.Generator | None = None
    ) -> None:
        super().__init__()
        _check_hyper(rank, alpha, 0.0, embed_dim, embed_dim, "LoRAInProj")
        kw = {"dtype": like.dtype, "device": like.device}
        self.lora_A = nn.Parameter(torch.empty(3, rank, embed_dim, **kw))
        self.lora_B = nn.Parameter(torch.empty(3, embed_dim, rank, **kw))
        self.register_buffer("lora_scale", torch.tensor(alpha / rank, **kw))
        for i in range(3):
            _init_pair(self.lora_A[i], self.lora_B[i], generator)

    def forward(self, weight: Tensor) -> Tensor:
        delta = torch.bmm(self.lora_B, self.lora_A)  # (3, E, E): q, k, v updates
        return weight + self.lora_scale * delta.reshape(weight.shape)


def _adapt_attention(
    mha: nn.MultiheadAttention, rank: int, alpha: float, dropout: float, name: str, generator: torch.Generator | None
) -> list[str]:
    """LoRA on the packed q/k/v projection (parametrization) and on ``out_proj`` (LoRALinear)."""
    if not mha._qkv_same_embed_dim or mha.in_proj_weight is None:
        raise MotionDataError(name, "LoRA supports attention with packed q/k/v (kdim == vdim == embed_dim) only")
    mha.in_proj_weight.requires_grad_(False)
    adapter = LoRAInProj(mha.embed_dim, rank, alpha, mha.in_proj_weight, generator)
    parametrize.register_parametrization(mha, _IN_PROJ, adapter)
    mha.out_proj = LoRALinear(mha.out_proj, rank, alpha, dropout, generator)  # type: ignore[assignment]
    return [f"{name}.{_IN_PROJ}", f"{name}.out_proj"]


def _is_adapted(module: nn.Module) -> bool:
    return isinstance(module, LoRALinear) or parametrize.is_parametrized(module, _IN_PROJ)


def _matches(name: str, targets: Iterable[str]) -> bool:
    """A target names a module by its last name component(s): ``linear1`` or ``layers.0.linear1``."""
    return any(name == t or name.endswith("." + t) for t in targets)


def _adaptable(root: nn.Module, prefix: str) -> Iterator[tuple[str, nn.Module]]:
    """``root`` itself if it is a Linear or MHA, else its Linear/MHA descendants (not inside an MHA)."""
    if isinstance(root, (nn.Linear, nn.MultiheadAttention)):
        yield prefix, root
        return
    for child_name, child in root.named_children():
        yield from _adaptable(child, f"{prefix}.{child_name}" if prefix else child_name)


def _set_submodule(model: nn.Module, name: str, module: nn.Module) -> None:
    parent_name, _, leaf = name.rpartition(".")
    setattr(model.get_submodule(parent_name) if parent_name else model, leaf, module)


def apply_lora(
    model: nn.Module,
    rank: int = 8,
    alpha: float = 16.0,
    targets: tuple[str, ...] = DEFAULT_TARGETS,
    dropout: float = 0.0,
    generator: torch.Generator | None = None,
) -> list[str]:
    """Freeze ``model`` and add adapters to the targeted modules; returns the adapted names.

    ``generator`` draws the A matrices (default: torch's global RNG); pass a seeded one for a reproducible artefact.

    A target matching an ``nn.MultiheadAttention`` adapts its q/k/v in-projection and ``out_proj``; one
    matching an ``nn.Linear`` wraps it; one matching a container adapts every Linear/MHA inside it.
    """
    if any(_is_adapted(m) for m in model.modules()):
        raise MotionDataError(type(model).__name__, "model already has LoRA adapters (merge or rebuild it first)")
    found = [(name, m) for name, m in model.named_modules() if name and _matches(name, targets)]
    todo: dict[str, nn.Module] = {}
    for name, module in found:
        todo.update(_adaptable(module, name))
    model.requires_grad_(False)
    adapted: list[str] = []
    for name, module in todo.items():
        if isinstance(module, nn.MultiheadAttention):
            adapted += _adapt_attention(module, rank, alpha, dropout, name, generator)
        elif not any(name.startswith(f"{other}.") for other, m in todo.items() if isinstance(m, nn.MultiheadAttention)):
            _set_submodule(model, name, LoRALinear(module, rank, alpha, dropout, generator))  # type: ignore[arg-type]
            adapted.append(name)
    if not adapted:
        raise MotionDataError(type(model).__name__, f"no Linear or MultiheadAttention matches LoRA targets {targets}")
    return sorted(adapted)


def is_lora_key(key: str) -> bool:
    """An adapter tensor's state-dict key (A, B, scale)."""
    return key.rpartition(".")[2].startswith(LORA_PREFIX)


def lora_state_dict(model: nn.Module) -> dict[str, Tensor]:
    """Only the adapter tensors (A, B and their scale), detached and contiguous (safetensors-ready)."""
    return {k: v.detach().contiguous().clone() for k, v in model.state_dict().items() if is_lora_key(k)}


def load_lora_state_dict(model: nn.Module, state: dict[str, Tensor]) -> None:
    """Copy adapter tensors into a model that ``apply_lora`` prepared the same way; keys and shapes must match."""
    own = {k: v for k, v in model.state_dict().items() if is_lora_key(k)}
    if not own:
        raise MotionDataError("LoRA state", "model has no LoRA adapters; call apply_lora first")
    _check_same_tensors("LoRA state", own, state)
    model.load_state_dict(state, strict=False)


def _check_same_tensors(what: str, own: Mapping[str, Tensor], state: Mapping[str, Tensor]) -> None:
    """A saved state fits the model's: the same keys, each of the same shape."""
    missing, unexpected = sorted(set(own) - set(state)), sorted(set(state) - set(own))
    if missing or unexpected:
        raise MotionDataError(what, f"keys differ: missing {missing[:3]}, unexpected {unexpected[:3]}")
    for key, value in state.items():
        if tuple(value.shape) != tuple(own[key].shape):
            raise MotionDataError(what, f"{key} has shape {tuple(value.shape)}, model expects {tuple(own[key].shape)}")


def merge_lora(model: nn.Module) -> nn.Module:
    """Fold every adapter into its base weight in place, restoring plain modules; returns ``model``."""
    for _name, module in list(model.named_modules()):
        if parametrize.is_parametrized(module, _IN_PROJ):
            parametrize.remove_parametrizations(module, _IN_PROJ, leave_parametrized=True)
            module.in_proj_weight.requires_grad_(False)
    for name, module in list(model.named_modules()):
        if isinstance(module, LoRALinear):
            _set_submodule(model, name, module.merged())
    return model


def base_state_dict(model: nn.Module) -> dict[str, Tensor]:
    """The frozen base weights of an adapted model under the plain model's keys (adapters left out)."""
    wrapped = tuple(f"{name}.base." for name, m in model.named_modules() if isinstance(m, LoRALinear))
    out: dict[str, Tensor] = {}
    for key, value in model.state_dict().items():
        if is_lora_key(key):
            continue
        key = key.replace(f"parametrizations.{_IN_PROJ}.original", _IN_PROJ)
        prefix = next((p for p in wrapped if key.startswith(p)), None)
        out[key if prefix is None else prefix[: -len("base.")] + key[len(prefix) :]] = value
    return out


def adapted_biases(model: nn.Module, extra: Iterable[str] = ()) -> dict[str, nn.Parameter]:
    """Biases of the adapted layers and of the Linear modules named in ``extra``, by state-dict key (BitFit).

    A low-rank delta acts on per-frame activations, so a shift held over a whole clip (a chest kept up) costs it
    rank; a bias carries such a shift for a few hundred numbers a layer.
    """
    found: dict[str, nn.Parameter] = {}
    for name, module in model.named_modules():
        if isinstance(module, LoRALinear):
            bias, key = module.base.bias, f"{name}.base.bias"
        elif parametrize.is_parametrized(module, _IN_PROJ):
            bias, key = getattr(module, "in_proj_bias", None), f"{name}.in_proj_bias"
        elif isinstance(module, nn.Linear) and name and _matches(name, extra) and not name.endswith(".base"):
            bias, key = module.bias, f"{name}.bias"
        else:
            continue
        if bias is not None:
            found[key] = bias
    return found


def load_biases(own: dict[str, nn.Parameter], state: dict[str, Tensor]) -> None:
    """Copy saved biases into ``own`` (what ``adapted_biases`` found, possibly nothing); keys and shapes must match."""
    _check_same_tensors("LoRA biases", own, state)
    with torch.no_grad():
        for key, value in state.items():
            own[key].copy_(value)


def count_lora_bytes(model: nn.Module) -> int:
    """Bytes of the adapter tensors, i.e. of the per-style artefact's weights."""
    return sum(t.numel() * t.element_size() for t in lora_state_dict(model).values())
