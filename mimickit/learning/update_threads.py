"""Thread settings of the update phase: torch's own ops on one thread, MKL's matrix products on all.

An update is thousands of small torch ops (elementwise, ReLU, gathers, optimiser terms) around a few
hundred matrix products. With two OpenMP threads every op is a parallel region whose end waits for both
threads; on a loaded machine the second thread is often descheduled, so each op waits a time slice.
`mimickit bench --train` on the shared 2-core machine (load 8-12): the PPO update took 10-36 s on two
threads against 5.2-5.4 s here (`benchmarks/update_paths.py`).

Only the matrix products keep every thread, through MKL's thread-local setting: the products are the
costly part and MKL partitions some of them (the small-output weight gradients, 28×256 from a batch of
1024) by the thread count, so their rounding depends on it. Keeping MKL's count keeps the weights bit for
bit those of the all-threads update (tested), while torch's elementwise ops do not depend on the count.

MKL's `MKL_Set_Num_Threads_Local` is looked up in torch's own library; where torch has no MKL (or the
symbol is absent), `update_threads()` changes nothing and the update runs as before.
"""

from __future__ import annotations

import ctypes
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from functools import cache
from pathlib import Path

import torch


@cache
def _mkl_set_local_threads() -> Callable[[int], int] | None:
    """MKL's C `MKL_Set_Num_Threads_Local(n)` (returns the previous local count; 0 = use the global
    count), or None when torch's library does not export it."""
    if not torch.backends.mkl.is_available():
        return None
    lib_path = Path(torch.__file__).parent / "lib" / "libtorch_cpu.so"
    try:
        fn = ctypes.CDLL(str(lib_path)).MKL_Set_Num_Threads_Local
    except (OSError, AttributeError):
        return None
    fn.argtypes = [ctypes.c_int]
    fn.restype = ctypes.c_int
    return fn


def mkl_local_threads_available() -> bool:
    """True when `update_threads()` can split the thread settings (torch with MKL's symbol)."""
    return _mkl_set_local_threads() is not None


@contextmanager
def update_threads() -> Iterator[None]:
    """Run the block with torch's intra-op ops on one thread and MKL's on the caller's torch count."""
    n = torch.get_num_threads()
    set_local = _mkl_set_local_threads()
    if n <= 1 or set_local is None:
        yield
        return
    torch.set_num_threads(1)  # also sets MKL's global count to 1 ...
    prev_local = set_local(n)  # ... which this thread's local count overrides
    try:
        yield
    finally:
        set_local(prev_local)
        torch.set_num_threads(n)
