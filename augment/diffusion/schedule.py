"""Noise schedule: betas and every quantity derived from them, plus MDM-style timestep respacing.

A schedule owns numbers only (no networks, no sampling loop). All tables are float64 so that
1000-step products stay accurate; they are cast to the sample's dtype when extracted.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import Tensor

from motionaug.schemas.errors import MotionDataError

NUM_TRAIN_TIMESTEPS = 1000


def cosine_alpha_bar(u: float, s: float = 0.008) -> float:
    """Nichol & Dhariwal's cosine alpha_bar(u) for u in [0, 1] (MDM's 'cosine' schedule)."""
    return math.cos((u + s) / (1.0 + s) * math.pi / 2.0) ** 2


def cosine_betas(num_timesteps: int = NUM_TRAIN_TIMESTEPS, s: float = 0.008, max_beta: float = 0.999) -> Tensor:
    """Betas discretising the cosine alpha_bar, clipped at ``max_beta`` so the last step stays invertible."""
    betas = [
        min(1.0 - cosine_alpha_bar((i + 1) / num_timesteps, s) / cosine_alpha_bar(i / num_timesteps, s), max_beta)
        for i in range(num_timesteps)
    ]
    return torch.tensor(betas, dtype=torch.float64)


def space_timesteps(num_timesteps: int, section_counts: str | int | Sequence[int]) -> list[int]:
    """Kept timesteps of a ``num_timesteps`` process, MDM's ``space_timesteps`` semantics, sorted ascending.

    ``"ddimN"``: the DDIM paper's integer stride (``range(0, T, stride)`` with exactly N entries).
    ``"10,15,20"`` or ``[10, 15, 20]``: equal sections of the process, each strided to that many steps.
    An ``int`` N means ``"ddimN"`` when an integer stride exists, else one evenly rounded section of N.
    """
    source = f"space_timesteps({section_counts!r})"
    if isinstance(section_counts, int):
        return _ddim_steps(num_timesteps, section_counts) or _section_steps(num_timesteps, [section_counts], source)
    if isinstance(section_counts, str):
        if section_counts.startswith("ddim"):
            count = _parse_int(section_counts[len("ddim") :], source)
            steps = _ddim_steps(num_timesteps, count)
            if not steps:
                raise MotionDataError(source, f"no integer stride gives exactly {count} of {num_timesteps} steps")
            return steps
        counts = [_parse_int(part, source) for part in section_counts.split(",")]
        return _section_steps(num_timesteps, counts, source)
    return _section_steps(num_timesteps, [int(c) for c in section_counts], source)


def _parse_int(text: str, source: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise MotionDataError(source, f"{text!r} is not a step count") from None


def _ddim_steps(num_timesteps: int, count: int) -> list[int]:
    """``range(0, T, stride)`` with exactly ``count`` entries, or [] when no integer stride gives that."""
    if count == num_timesteps:
        return list(range(num_timesteps))
    for stride in range(1, num_timesteps):
        if len(range(0, num_timesteps, stride)) == count:
            return list(range(0, num_timesteps, stride))
    return []


def _section_steps(num_timesteps: int, counts: list[int], source: str) -> list[int]:
    """Split the process into ``len(counts)`` sections and stride each to its count (fractional stride, rounded)."""
    size_per, extra = divmod(num_timesteps, len(counts))
    start, kept = 0, []
    for i, count in enumerate(counts):
        size = size_per + (1 if i < extra else 0)
        if count < 1 or count > size:
            raise MotionDataError(source, f"cannot take {count} steps from a section of {size}")
        stride = 1.0 if count == 1 else (size - 1) / (count - 1)
        kept += [start + round(j * stride) for j in range(count)]
        start += size
    return sorted(set(kept))


class NoiseSchedule:
    """Betas of a (possibly respaced) diffusion process and the tables q/p formulas need.

    Index ``i`` runs over this schedule's own steps (0..S-1); ``timesteps[i]`` is the original training
    timestep the network is conditioned on (the identity for an unspaced schedule).
    """

    def __init__(self, betas: Tensor, timesteps: Tensor | None = None, num_train_timesteps: int | None = None) -> None:
        betas = torch.as_tensor(betas, dtype=torch.float64)
        if betas.ndim != 1 or not bool(((betas > 0) & (betas <= 1)).all()):
            raise MotionDataError("NoiseSchedule", "betas must be a 1-D tensor with values in (0, 1]")
        self.betas = betas
        self.timesteps = torch.arange(len(betas)) if timesteps is None else torch.as_tensor(timesteps, dtype=torch.long)
        self.num_train_timesteps = num_train_timesteps or len(betas)
        self.alphas = 1.0 - betas
        self.alphas_cumprod = torch.cumprod(self.alphas, dim=0)
        one = torch.ones(1, dtype=torch.float64)
        self.alphas_cumprod_prev = torch.cat([one, self.alphas_cumprod[:-1]])
        self.sqrt_alphas_cumprod = self.alphas_cumprod.sqrt()
        self.sqrt_one_minus_alphas_cumprod = (1.0 - self.alphas_cumprod).sqrt()
        self.sqrt_recip_alphas_cumprod = (1.0 / self.alphas_cumprod).sqrt()
        self.sqrt_recipm1_alphas_cumprod = (1.0 / self.alphas_cumprod - 1.0).sqrt()
        # q(x_{t-1} | x_t, x_0): variance beta_tilde and the two mean coefficients
        self.posterior_variance = betas * (1.0 - self.alphas_cumprod_prev) / (1.0 - self.alphas_cumprod)
        # beta_tilde_0 = 0; the log is clipped with beta_tilde_1 as in guided-diffusion/MDM
        clipped = torch.cat([self.posterior_variance[1:2], self.posterior_variance[1:]])
        self.posterior_log_variance_clipped = clipped.log()
        self.posterior_mean_coef1 = betas * self.alphas_cumprod_prev.sqrt() / (1.0 - self.alphas_cumprod)
        self.posterior_mean_coef2 = (1.0 - self.alphas_cumprod_prev) * self.alphas.sqrt() / (1.0 - self.alphas_cumprod)

    @classmethod
    def cosine(cls, num_timesteps: int = NUM_TRAIN_TIMESTEPS) -> NoiseSchedule:
        """MDM's default schedule: cosine alpha_bar, s=0.008, betas clipped at 0.999."""
        return cls(cosine_betas(num_timesteps))

    def __len__(self) -> int:
        return int(self.betas.shape[0])

    @property
    def is_respaced(self) -> bool:
        return len(self) != self.num_train_timesteps

    def respace(self, spec: str | int | Sequence[int]) -> NoiseSchedule:
        """A schedule over the kept timesteps (``space_timesteps`` semantics), alpha_bar equal to the original's there.

        The new betas are ``1 - alpha_bar[t_k] / alpha_bar[t_{k-1}]`` (MDM's SpacedDiffusion), so q(x_t | x_0)
        is unchanged at every kept timestep.
        """
        if self.is_respaced:
            raise MotionDataError("NoiseSchedule.respace", "respace the original schedule, not a respaced one")
        kept = space_timesteps(len(self), spec)
        alpha_bar = self.alphas_cumprod[kept]
        prev = torch.cat([torch.ones(1, dtype=torch.float64), alpha_bar[:-1]])
        return NoiseSchedule(1.0 - alpha_bar / prev, torch.tensor(kept), self.num_train_timesteps)


def extract(table: Tensor, index: Tensor, like: Tensor) -> Tensor:
    """``table[index]`` as ``like``'s dtype/device, shaped (B, 1, ..., 1) to broadcast against ``like``."""
    values = table.to(like.device)[index.to(like.device)].to(like.dtype)
    return values.reshape(-1, *([1] * (like.ndim - 1)))


def start_step_for(noise_timestep: int, steps: int, num_timesteps: int = NUM_TRAIN_TIMESTEPS) -> int:
    """Sampler ``start_step`` (denoising steps to run) matching a noise level given in training timesteps.

    ``start_step=n`` noises the input to respaced index ``n - 1`` and runs ``n`` steps down to 0. With 20 DDIM
    steps of 1000 the kept timesteps are 0, 50, ..., 950, so K=300 maps to n=6 (noise at t=250, model
    called at t=250, 200, ..., 0): ``round(K * steps / T)``, at least 1 and at most ``steps``.
    """
    if not 0 <= noise_timestep <= num_timesteps:
        raise MotionDataError("start_step_for", f"noise timestep {noise_timestep} outside [0, {num_timesteps}]")
    return min(max(round(noise_timestep * steps / num_timesteps), 1), steps)
