"""Reading a run's `metrics.jsonl` (one JSON object per line, one line per iteration, plus a marker row
`{"event": "resume", ...}` per resume), and the rows it appended since the last read (`RowReader`, which
`GET /api/stream` follows): the source of the live curves.

The trainer writes a non-finite value as the JSON tokens NaN / Infinity / -Infinity, which a browser's
JSON.parse refuses (and Starlette's JSON responses too). Each row leaves here with such a value as
null and a `nonfinite` object naming it: `{"critic_loss": null, "nonfinite": {"critic_loss": "nan"}}`,
so the page can mark where a curve went non-finite instead of losing the point.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from mimickit.learning.run_folder import METRICS_FILE

__all__ = ["METRICS_FILE", "RowReader", "last_rows", "read_rows"]
TAIL_BYTES = 256 * 1024


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


def last_rows(path: Path, n: int = 50) -> list[dict[str, Any]]:
    """The last `n` complete rows, reading only the file's tail (a run list polls every run)."""
    try:
        with path.open("rb") as f:
            size = f.seek(0, 2)
            f.seek(max(0, size - TAIL_BYTES))
            chunk = f.read()
    except OSError:
        return []
    lines = chunk.split(b"\n")[:-1]  # the part after the last newline is not a complete row yet
    if len(chunk) < size and lines:
        lines = lines[1:]  # the first line may start mid-row
    rows = [r for r in (_parse(line) for line in lines) if r is not None]
    return rows[-n:]


def _parse(line: bytes) -> dict[str, Any] | None:
    try:
        row = json.loads(line)
    except ValueError:
        return None  # a corrupt line is skipped, not fatal to the stream
    return browser_safe(row) if isinstance(row, dict) else None


def browser_safe(row: dict[str, Any]) -> dict[str, Any]:
    """The row with each non-finite number as null, named in `nonfinite` (column -> nan/inf/-inf)."""
    bad = {k: _token(v) for k, v in row.items() if isinstance(v, float) and not math.isfinite(v)}
    if not bad:
        return row
    return {**{k: (None if k in bad else v) for k, v in row.items()}, "nonfinite": bad}


def _token(v: float) -> str:
    return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")


class RowReader:
    """The rows a growing `metrics.jsonl` gained since the last `read()`: (index, row) pairs, a half-written
    last line kept for the next call. Blocking file I/O: call it from a worker thread in async code."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._pos, self._index, self._pending = 0, 0, b""

    def read(self) -> list[tuple[int, dict[str, Any]]]:
        chunk = b""
        if self.path.is_file():
            with self.path.open("rb") as f:
                f.seek(self._pos)
                chunk = f.read()
            self._pos += len(chunk)
        self._pending += chunk
        *lines, self._pending = self._pending.split(b"\n")
        out = []
        for line in lines:
            row = _parse(line)
            if row is not None:
                out.append((self._index, row))
                self._index += 1
        return out
