"""Reading a run's `metrics.jsonl` (one JSON object per line, one line per iteration, plus a marker row
`{"event": "resume", ...}` per resume), and the rows it appended since the last read (`RowReader`, which
`GET /api/stream` follows): the source of the live curves.

The trainer writes a non-finite value as the JSON tokens NaN / Infinity / -Infinity, which a browser's
JSON.parse refuses (and Starlette's JSON responses too). Each row leaves here with such a value as
null and a `nonfinite` object naming it: `{"critic_loss": null, "nonfinite": {"critic_loss": "nan"}}`,
so the page can mark where a curve went non-finite instead of losing the point.
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from mimickit.learning.run_folder import METRICS_FILE

__all__ = ["METRICS_FILE", "MetricsCsv", "RowReader", "last_rows", "read_rows"]
TAIL_BYTES = 256 * 1024
MAX_CSV_COLUMNS = 2000  # a run writes some dozens; more is not a metrics file a spreadsheet should get
CSV_CHUNK_ROWS = 500  # rows per chunk of the streamed answer


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


class MetricsCsv:
    """Runs' `metrics.jsonl` files as one CSV: the columns are the union of the rows' keys in the order
    they first appear (after a `run` column when `label` names each file's run), a row per complete line
    of each file in turn, a key a row lacks left empty. The columns are read first (one pass), so the
    file is read twice; each file is read only up to the size it had then, so a row the trainer
    appends meanwhile (with perhaps a new key) is not half in the answer."""

    def __init__(self, files: list[tuple[str | None, Path]]) -> None:
        self.files = files
        self.sizes: list[int] = []
        keys: dict[str, None] = {}
        for _, path in files:
            size = path.stat().st_size if path.is_file() else 0
            self.sizes.append(size)
            for row in _rows_upto(path, size):
                keys.update(dict.fromkeys(row))
        labelled = any(label is not None for label, _ in files)
        self.columns = (["run"] if labelled else []) + list(keys)

    def chunks(self) -> Iterator[str]:
        """The CSV text, some hundred rows a chunk (blocking reads: a streamed answer's worker thread)."""
        buf = io.StringIO()
        out = csv.writer(buf, lineterminator="\n")
        out.writerow(self.columns)
        labelled = self.columns[:1] == ["run"]
        keys = self.columns[1:] if labelled else self.columns
        n = 0
        for (label, path), size in zip(self.files, self.sizes, strict=True):
            for row in _rows_upto(path, size):
                cells = [csv_cell(row.get(k)) for k in keys]
                out.writerow([label, *cells] if labelled else cells)
                n += 1
                if n % CSV_CHUNK_ROWS == 0:
                    yield buf.getvalue()
                    buf.seek(0)
                    buf.truncate()
        yield buf.getvalue()


def _rows_upto(path: Path, size: int) -> Iterator[dict[str, Any]]:
    """The file's complete rows in its first `size` bytes, as read raw (NaN stays a float nan: the CSV
    writes it as `nan`, not as an empty cell); a corrupt line is skipped as `read_rows` skips it."""
    if size == 0:
        return
    with path.open("rb") as f:
        left = size
        for line in f:
            left -= len(line)
            if left < 0 or not line.endswith(b"\n"):
                return
            try:
                row = json.loads(line)
            except ValueError:
                continue
            if isinstance(row, dict):
                yield row


def csv_cell(v: Any) -> str:
    """One value as a CSV cell: numbers as Python writes them (`repr`: every digit of a float, `nan`,
    `inf`), booleans as JSON writes them, a missing value empty, a nested value as its JSON."""
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float, str)):
        return repr(v) if isinstance(v, float) else str(v)
    return json.dumps(v, separators=(",", ":"))
