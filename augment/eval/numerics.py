"""Pinned CPU numerics for the judges' fit: the same command, seed and threads give the same weights on any x86-64
CPU with AVX2, Intel or AMD (docs/protocol.md, "One fit, one instrument").

Libraries pick kernels by the CPU, and kernels sum floats in their own order. The pin fixes each one's path: ATen's
AVX2 kernels; MKL's reproducibility branch ``COMPATIBLE`` (SSE2, fixed cache sizes and reduction order: the one
branch MKL documents for non-Intel CPUs too) at a fixed thread count; and no oneDNN or NNPACK (oneDNN promises equal
results on one platform only), so convolutions run on ATen and MKL. The variables act only from a process's start:
``pinned_env`` is the environment to start one with, and ``pinned_kernels`` wraps the fit inside it.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping
from contextlib import contextmanager

import torch

from motionaug.schemas.errors import MotionDataError

PINNED_ENV = {"ATEN_CPU_CAPABILITY": "avx2", "MKL_CBWR": "COMPATIBLE", "MKL_DYNAMIC": "FALSE", "OMP_DYNAMIC": "FALSE"}
"""Read by ATen and MKL (OpenMP) when they start: set before the process runs, never from inside it."""


def pinned_env(base: Mapping[str, str] | None = None) -> dict[str, str]:
    """``base`` (this process's environment by default) with ``PINNED_ENV`` over it: a pinned process's environment."""
    return {**(os.environ if base is None else base), **PINNED_ENV}


def pinned() -> bool:
    """Whether this process was given the pinned environment."""
    return all(os.environ.get(key) == value for key, value in PINNED_ENV.items())


@contextmanager
def pinned_kernels() -> Iterator[dict[str, object]]:
    """oneDNN and NNPACK off within, in a process started with ``pinned_env``; yields the settings, for the fit's
    record. Raises where the process was not started pinned or ATen could not take its AVX2 kernels."""
    if not pinned():
        raise MotionDataError("pinned numerics", "start the process with pinned_env() (the variables act at start)")
    capability = torch.backends.cpu.get_cpu_capability()
    if capability != "AVX2":
        raise MotionDataError("pinned numerics", f"ATen runs {capability} kernels, not AVX2: the CPU lacks AVX2")
    onednn = torch.backends.mkldnn.enabled  # (its flags() would reset its TF32 settings too, with a warning)
    torch.backends.mkldnn.enabled = False
    try:
        with torch.backends.nnpack.flags(enabled=False):
            yield {"env": dict(PINNED_ENV), "onednn": False, "nnpack": False, "torch": torch.__version__}
    finally:
        torch.backends.mkldnn.enabled = onednn
