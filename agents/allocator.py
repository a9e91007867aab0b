"""Keep freed memory in the process for training's large, short-lived tensors.

A training step makes and frees tensors of 1–30 MB many times per update (messages over ~68,000
directed edges × 32 features, their gradients). glibc's malloc serves blocks above its dynamic
mmap threshold (128 kB at start) with a fresh ``mmap`` and returns them to the kernel on
``free``, so every such tensor is page-faulted and zeroed by the kernel again (system time,
and cold caches for the step that reads it).
:func:`retain_freed_memory` raises the mmap threshold to 32 MB and the trim threshold to 2 GB
(``mallopt``, the same settings as ``MALLOC_MMAP_THRESHOLD_`` / ``MALLOC_TRIM_THRESHOLD_``), so
freed blocks are reused from the heap; the cost is resident memory that stays at its peak
(a few hundred MB for the cpu presets). Measured: docs/algorithms.md, "Cost".

No effect, and no error, where the C library is not glibc (macOS, musl).
"""

from __future__ import annotations

import ctypes
import ctypes.util

M_TRIM_THRESHOLD = -1  # glibc's mallopt parameter numbers (malloc.h)
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_BYTES = 32 * 2**20
TRIM_THRESHOLD_BYTES = 2**31 - 1  # the largest int


def retain_freed_memory() -> bool:
    """Set glibc's mmap and trim thresholds for this process; True if both were set."""
    name = ctypes.util.find_library("c")
    try:
        mallopt = ctypes.CDLL(name).mallopt
    except (OSError, AttributeError, TypeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    trimmed = mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)
    mapped = mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
    return bool(trimmed and mapped)
