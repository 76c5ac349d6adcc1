"""glibc's malloc thresholds for a training process: large tensors reused from the heap, not mapped afresh.

glibc serves a request above its mmap threshold (128 KiB at start) with a fresh `mmap` and gives it back
with `munmap` when freed, so every page of it faults again on its next use; it also returns freed memory
at the heap's top above 128 KiB. A training step allocates and frees many tensors of that size and more
(the envs' [256, ...] state, [1024, 512] activations and their gradients), so each one was paid for in
page faults. Raised thresholds keep those blocks in the heap for the next step (a process keeps up to
`TRIM_THRESHOLD` of freed memory). Measured in docs/benchmarks.md ("glibc's malloc thresholds").

The process's owner calls `tune_malloc()` once at start (`mimickit train/test`, `mimickit bench`), as
it sets torch's thread count; a library import never does. Where malloc is not glibc's, or the user
set any `MALLOC_*_` variable of glibc's own, nothing changes.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
from collections.abc import Callable

# mallopt's parameter numbers (glibc's malloc.h)
M_TRIM_THRESHOLD, M_TOP_PAD, M_MMAP_THRESHOLD = -1, -2, -3
MMAP_THRESHOLD = 64 << 20  # bytes: a request below this comes from the heap
TRIM_THRESHOLD = 256 << 20  # bytes of free memory at the heap's top kept rather than returned
TOP_PAD = 64 << 20  # bytes the heap grows by beyond a request, so that growth is rare
GLIBC_VARS = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_TOP_PAD_", "MALLOC_MMAP_MAX_")


def tune_malloc() -> dict[str, int] | None:
    """Set glibc's thresholds for this process; the values set, or None when nothing was changed
    (not glibc, or the user set glibc's own `MALLOC_*_` variables, which then stand)."""
    if any(v in os.environ for v in GLIBC_VARS):
        return None
    mallopt = _mallopt()
    if mallopt is None:
        return None
    settings = {"mmap_threshold": MMAP_THRESHOLD, "trim_threshold": TRIM_THRESHOLD, "top_pad": TOP_PAD}
    params = {"mmap_threshold": M_MMAP_THRESHOLD, "trim_threshold": M_TRIM_THRESHOLD, "top_pad": M_TOP_PAD}
    for name, value in settings.items():
        if mallopt(params[name], value) != 1:  # glibc returns 1 on success
            return None
    return settings


def _mallopt() -> Callable[[int, int], int] | None:
    """glibc's `mallopt(int, int)`, or None where the C library is not glibc."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.gnu_get_libc_version  # noqa: B018 - only glibc has it
        fn = libc.mallopt
    except (OSError, AttributeError):
        return None
    fn.argtypes = [ctypes.c_int, ctypes.c_int]
    fn.restype = ctypes.c_int
    return fn
