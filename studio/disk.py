"""A full, over-quota or read-only disk as one line and the HTTP status that says so.

Every writer of the studio (the registry, uploads, run folders, jobs, exports) can meet one. The server
answers it with 507 (no space: full or over quota) or 503 (read-only, not permitted, an I/O error: the
server cannot write there now), never a 500 with a traceback, and keeps answering reads.
"""

from __future__ import annotations

import errno
import os
import sqlite3
from pathlib import Path

from mimickit.util.errors import MimicKitError

NO_SPACE = 507
CANNOT_WRITE = 503
MAX_NAME_CHARS = 200
MIN_FREE_BYTES = 1 << 20
"""What a new run needs free at least: its checkpoint alone takes megabytes."""
_ERRNOS = {
    errno.ENOSPC: (NO_SPACE, "cannot write", "its disk is full"),
    errno.EDQUOT: (NO_SPACE, "cannot write", "its disk quota is used up"),
    errno.EROFS: (CANNOT_WRITE, "cannot write", "its disk is read-only"),
    errno.EACCES: (CANNOT_WRITE, "cannot use", "permission denied"),
    errno.EPERM: (CANNOT_WRITE, "cannot use", "not permitted"),
}
# sqlite3 says these in its OperationalError's text (it keeps the errno to itself).
_SQLITE = {
    "database or disk is full": (NO_SPACE, "cannot write", "its disk is full"),
    "attempt to write a readonly database": (CANNOT_WRITE, "cannot write", "its disk or file is read-only"),
    "disk i/o error": (CANNOT_WRITE, "cannot use", "disk I/O error (is its disk full or read-only?)"),
    "unable to open database file": (CANNOT_WRITE, "cannot open", "is its disk full or read-only?"),
}


class DiskError(MimicKitError):
    """A write the disk refused, as one line; `status` is the HTTP status (507 or 503). A MimicKitError,
    so a CLI prints it as its one `error:` line."""

    def __init__(self, message: str, status: int) -> None:
        super().__init__(message)
        self.status = status


def disk_error(e: BaseException, what: str | Path | None = None) -> DiskError | None:
    """`e` (or the error it was raised from) as a DiskError when a disk refused a write, else None.
    `what`: the thing written, as the line names it (default: the OSError's file name)."""
    for cause in _chain(e):
        known = _known(cause)
        if known is not None:
            status, verb, why = known
            name = what if what is not None else getattr(cause, "filename", None)
            shown = _short(str(name)) if name else "a file"
            return DiskError(f"{verb} {shown}: {why}", status)
    return None


def require_space(folder: Path, what: str) -> None:
    """DiskError when `folder`'s disk is read-only (503) or has less than `MIN_FREE_BYTES` free (507):
    for a write that would succeed while what it starts cannot (SQLite reuses its WAL on a full disk,
    a run's folder needs megabytes). `what`: the thing refused, e.g. "queue a run"."""
    try:
        st = os.statvfs(folder)
    except OSError:
        return  # no such folder yet: the write itself will say what is wrong
    if st.f_flag & os.ST_RDONLY:
        raise DiskError(f"cannot {what} in {_short(str(folder))}: its disk is read-only", CANNOT_WRITE)
    free = st.f_bavail * st.f_frsize
    if free < MIN_FREE_BYTES:
        raise DiskError(f"cannot {what} in {_short(str(folder))}: its disk is full ({free} bytes free)", NO_SPACE)


def _known(e: BaseException) -> tuple[int, str, str] | None:
    if isinstance(e, OSError):
        return _ERRNOS.get(e.errno or 0)
    if isinstance(e, sqlite3.OperationalError):
        text = str(e).lower()
        return next((v for k, v in _SQLITE.items() if k in text), None)
    return None


def _chain(e: BaseException, depth: int = 5) -> list[BaseException]:
    """`e`, then what it was raised from or during (a wrapper's OSError), at most `depth` deep."""
    out: list[BaseException] = []
    cur: BaseException | None = e
    while cur is not None and len(out) < depth and cur not in out:
        out.append(cur)
        cur = cur.__cause__ or cur.__context__
    return out


def _short(text: str) -> str:
    return text if len(text) <= MAX_NAME_CHARS else "…" + text[-(MAX_NAME_CHARS - 1) :]
