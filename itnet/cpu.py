"""What this CPU does fast, and the allocator setting that keeps torch steady on it.

No torch here: ``itnet bench`` describes the machine with it, training asks it whether bfloat16
pays (it does only with AMX or AVX-512 BF16: without them torch emulates bf16 matmuls, measured
at 56 against 196 GFLOP/s of float32 on a 2-core AVX-512 Xeon, and a training step 20% slower).
"""

from __future__ import annotations

import ctypes
import functools
import os
import platform
from pathlib import Path

MATRIX_ISA = ("avx2", "avx512f", "avx512_vnni", "avx512_bf16", "amx_bf16", "amx_int8")
BF16_ISA = frozenset({"avx512_bf16", "amx_bf16"})
M_MMAP_THRESHOLD = -3  # glibc's mallopt parameter (malloc.h)
MMAP_THRESHOLD_BYTES = 32 * 1024 * 1024


@functools.cache
def cpu_info(cpuinfo: Path = Path("/proc/cpuinfo")) -> tuple[str, frozenset[str]]:
    """(model name, instruction-set flags) of the first CPU; the platform's name and no flags
    where /proc/cpuinfo cannot be read."""
    name, flags = platform.processor() or platform.machine(), frozenset[str]()
    try:
        for line in cpuinfo.read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name":
                name = value.strip()
            elif key.strip() == "flags":
                flags = frozenset(value.split())
                break
    except OSError:
        pass
    return name, flags


def cpu_description() -> str:
    """CPU model, core count and the matrix instruction sets that decide the step time."""
    name, flags = cpu_info()
    isa = [f for f in MATRIX_ISA if f in flags]
    return f"{name}, {os.cpu_count()} CPUs" + (f" ({', '.join(isa)})" if isa else "")


def fast_bf16(device: str = "cpu") -> bool:
    """Whether bfloat16 matmuls beat float32 here: on a CPU with AMX or AVX-512 BF16; never on
    CUDA (the paper's recipe is float32 there)."""
    return device == "cpu" and bool(BF16_ISA & cpu_info()[1])


def keep_large_allocations() -> bool:
    """Stop glibc from returning torch's large buffers to the kernel after every step (the same
    as ``MALLOC_MMAP_THRESHOLD_=33554432``: page faults otherwise take half the CPU time of a
    training step). True when set; False where the C library has no ``mallopt``."""
    try:
        libc = ctypes.CDLL(None)
        return bool(libc.mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES))
    except (OSError, AttributeError):
        return False
