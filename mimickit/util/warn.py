"""The project's warnings (a clip's NaN columns, an MJCF's missing meshes, engine keys ignored, ...) and
how a caller collects them instead of printing them.

`warnings.catch_warnings` swaps the process-wide filters: two threads inside it at once restore each
other's state, so the studio's request threads may not use it. A caller that wants a build's warnings as
values (to show them once, or not at all) wraps the build in `collect_warnings()`; the list lives in a
context variable, which each thread has its own of. Outside one, `warn` is `warnings.warn`; the
`mimickit` command line prints those through `one_line_warnings()`: `warning: MESSAGE`, each message once
(the MJCF and the engine both load a character, and both would warn of its missing meshes).
"""

from __future__ import annotations

import sys
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar

_collected: ContextVar[list[str] | None] = ContextVar("mimickit_warnings", default=None)


def warn(message: str, stacklevel: int = 1) -> None:
    """`warnings.warn(message)` (a UserWarning, `stacklevel` counted from the caller), or, inside
    `collect_warnings()` in this thread, the message added to its list (once)."""
    collected = _collected.get()
    if collected is None:
        warnings.warn(message, stacklevel=stacklevel + 1)
    elif message not in collected:
        collected.append(message)


@contextmanager
def collect_warnings() -> Iterator[list[str]]:
    """The messages `warn` is given inside the block, in this thread (and context) only, each once."""
    collected: list[str] = []
    token = _collected.set(collected)
    try:
        yield collected
    finally:
        _collected.reset(token)


@contextmanager
def one_line_warnings() -> Iterator[None]:
    """Inside the block, each distinct warning message is printed once to stderr as `warning: MESSAGE`
    (not Python's `FILE:LINE: UserWarning: MESSAGE` plus a source line of ours)."""

    shown: set[str] = set()

    def show(message: Warning | str, *_args: object, **_kwargs: object) -> None:
        # Deduplicated here, not by the "once" filter: its registry is cleared whenever a module adds a filter.
        if str(message) not in shown:
            shown.add(str(message))
            print(f"warning: {message}", file=sys.stderr, flush=True)

    with warnings.catch_warnings():  # restores showwarning after the block
        warnings.showwarning = show
        yield
