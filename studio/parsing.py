"""Reading user files for the studio: never on the event loop, and clips with a time and memory budget.

A clip (`.pkl`) is untrusted: a crafted one can take seconds of CPU or gigabytes of memory inside
C code that holds the GIL (a worker thread would stall every request just the same) or, before the
loader was hardened, crash the process. So clips are read through `mimickit.anim.motion`'s guarded
loader (a child process with a time and memory budget) when it is there, and in-process otherwise;
either way the call runs in a worker thread (`run_blocking`), so the event loop keeps answering.

Everything else the studio parses for a request (a character's MJCF, a checkpoint, a config build)
is a plain blocking call in a sync endpoint, which FastAPI already runs in its thread pool.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import anyio.to_thread

from mimickit.anim import motion as motion_module
from mimickit.anim.motion import Motion

T = TypeVar("T")


def read_motion(path: Path, *, sanitize_nan: bool = True) -> Motion:
    """The clip at `path` (MimicKitError, one line, when it is not a readable clip or over a budget)."""
    guarded = getattr(motion_module, "load_motion_guarded", None)
    if guarded is not None:
        return guarded(path, sanitize_nan=sanitize_nan)
    return motion_module.load_motion(path, sanitize_nan=sanitize_nan)


def read_motion_bytes(data: bytes, *, source: str, sanitize_nan: bool = True) -> Motion:
    """The clip `data` holds (an upload), read as `read_motion` reads a file."""
    guarded = getattr(motion_module, "motion_from_bytes_guarded", None)
    if guarded is not None:
        return guarded(data, source=source, sanitize_nan=sanitize_nan)
    return motion_module.motion_from_bytes(data, source=source, sanitize_nan=sanitize_nan)


async def run_blocking(fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
    """`fn(*args, **kwargs)` in a worker thread, awaited from an async endpoint."""
    return await anyio.to_thread.run_sync(functools.partial(fn, *args, **kwargs))
