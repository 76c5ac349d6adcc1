"""Reading user files for the studio: never on the event loop, and clips with a time and memory budget.

A clip (`.pkl`) is untrusted: a crafted one can take seconds of CPU or gigabytes of memory inside
C code that holds the GIL (a worker thread would stall every request just the same). So clips are
read through `mimickit.anim.motion`'s guarded loader (a child process with a time and memory budget),
called from a worker thread (`starlette.concurrency.run_in_threadpool` in async endpoints), so the
event loop keeps answering. The library's scan of the data folders parses in-process (see `read_motion`).

Everything else the studio parses for a request (a character's MJCF, a checkpoint, a config build)
is a plain blocking call in a sync endpoint, which FastAPI already runs in its thread pool.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

from mimickit.anim.motion import (
    Motion,
    load_motion,
    load_motion_guarded,
    motion_from_bytes_guarded,
)
from mimickit.util.errors import MimicKitError


def read_motion(path: Path, *, sanitize_nan: bool = True, in_child: bool = True) -> Motion:
    """The clip at `path` (MimicKitError, one line, when it is not a readable clip or over a budget).

    `in_child=False` parses in this process with the loader's own limits (bounds-checked tensors,
    frame, width and value counts checked before anything is converted): for the library's scan of
    the data folders, where a child per file would cost ~0.05-0.5 s times hundreds of clips. The
    scan runs in a background thread, never on the event loop."""
    load = load_motion_guarded if in_child else load_motion
    with _one_line(str(path)):
        return load(path, sanitize_nan=sanitize_nan)


def read_motion_bytes(data: bytes, *, source: str, sanitize_nan: bool = True) -> Motion:
    """The clip `data` holds (an upload), read in the guarded child as `read_motion` reads a file."""
    with _one_line(source):
        return motion_from_bytes_guarded(data, source=source, sanitize_nan=sanitize_nan)


@contextlib.contextmanager
def _one_line(source: str) -> Iterator[None]:
    """Whatever a crafted file makes the loader raise (an overflow, a memory error) is the file's
    fault: one MimicKitError line naming it, not an internal error."""
    try:
        yield
    except MimicKitError:
        raise
    except Exception as e:  # noqa: BLE001 - untrusted input: every failure is the same user error
        first = (str(e).strip().splitlines() or [""])[0][:200]
        raise MimicKitError(f"{source}: not a MimicKit clip ({type(e).__name__}: {first})") from None
