"""Reading a run's `metrics.jsonl` (one JSON object per line, one line per iteration), and following it
as the trainer appends: the source of the live curves.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

METRICS_FILE = "metrics.jsonl"
HEARTBEAT_S = 15.0


def read_rows(path: Path, start: int = 0) -> list[dict[str, Any]]:
    """Complete rows from index `start` on; a half-written last line is left for later."""
    if not path.is_file():
        return []
    rows = []
    with path.open("rb") as f:
        for line in f:
            row = _parse(line) if line.endswith(b"\n") else None
            if row is not None:
                rows.append(row)
    return rows[start:]


def _parse(line: bytes) -> dict[str, Any] | None:
    try:
        row = json.loads(line)
    except ValueError:
        return None  # a corrupt line is skipped, not fatal to the stream
    return row if isinstance(row, dict) else None


async def follow_rows(
    path: Path, finished: Callable[[], bool], start: int = 0, poll_s: float = 0.25
) -> AsyncIterator[tuple[int, dict[str, Any]] | None]:
    """Yield (index, row) for each row as it is written, `None` as a heartbeat when idle; end once the
    run has finished and the file holds nothing more."""
    pos, index, pending = 0, 0, b""
    idle = 0.0
    while True:
        done = finished()  # read before the file, so rows written just before the end are not lost
        chunk = b""
        if path.is_file():
            with path.open("rb") as f:
                f.seek(pos)
                chunk = f.read()
            pos += len(chunk)
        pending += chunk
        *lines, pending = pending.split(b"\n")
        for line in lines:
            row = _parse(line)
            if row is None:
                continue
            if index >= start:
                yield index, row
            index += 1
        if chunk:
            idle = 0.0
            continue
        if done:
            return
        await asyncio.sleep(poll_s)
        idle += poll_s
        if idle >= HEARTBEAT_S:
            idle = 0.0
            yield None
