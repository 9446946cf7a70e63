"""Where tensors run and in which precision: CUDA when present, else CPU; bf16 autocast where it pays off."""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path

import torch

from motionaug.schemas.errors import MotionDataError

DEVICE_ENV = "MOTIONAUG_DEVICE"


@lru_cache(maxsize=1)
def cpu_has_bf16() -> bool:
    """True when the CPU advertises native bf16 (AMX or AVX512-BF16), where bf16 matmuls beat fp32."""
    try:
        flags = Path("/proc/cpuinfo").read_text(encoding="utf-8", errors="replace")
    except OSError:
        return False
    return "amx_bf16" in flags or "avx512_bf16" in flags


def pick_device(preferred: str | None = None) -> torch.device:
    """``preferred`` (or ``$MOTIONAUG_DEVICE``) when given, else the current CUDA device when one is visible, else CPU.

    Inside a Ray task the visible GPUs are the ones Ray assigned, so ``cuda`` is the task's own GPU.
    """
    wanted = preferred or os.environ.get(DEVICE_ENV)
    if wanted:
        source = f"device {wanted!r}" + ("" if preferred else f" (${DEVICE_ENV})")
        try:
            device = torch.device(wanted)
        except RuntimeError:
            raise MotionDataError(source, "not a torch device; use cpu, cuda or cuda:N") from None
        if device.type == "cuda" and not torch.cuda.is_available():
            raise MotionDataError(source, "CUDA was asked for but torch sees no GPU")
        return device
    return torch.device("cuda", torch.cuda.current_device()) if torch.cuda.is_available() else torch.device("cpu")


def bf16_autocast(enabled: bool | None, device: torch.device | str = "cpu") -> torch.autocast:
    """bf16 autocast on ``device``; ``None`` = on for CUDA (tensor cores) and for CPUs with bf16 units."""
    kind = torch.device(device).type
    if enabled is None:
        enabled = kind == "cuda" or (kind == "cpu" and cpu_has_bf16())
    return torch.autocast(kind, dtype=torch.bfloat16, enabled=enabled)
