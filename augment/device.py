"""What the CPU can do fast: whether bf16 autocast pays off here (AMX / AVX512-BF16 matmuls)."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import torch


@lru_cache(maxsize=1)
def cpu_has_bf16() -> bool:
    """True when the CPU advertises native bf16 (AMX or AVX512-BF16), where bf16 matmuls beat fp32 (~3.5x on AMX)."""
    try:
        flags = Path("/proc/cpuinfo").read_text(encoding="utf-8", errors="replace")
    except OSError:
        return False
    return "amx_bf16" in flags or "avx512_bf16" in flags


def bf16_autocast(enabled: bool | None) -> torch.autocast:
    """CPU bf16 autocast; ``None`` = on where the CPU has bf16 units."""
    return torch.autocast("cpu", dtype=torch.bfloat16, enabled=cpu_has_bf16() if enabled is None else enabled)
