"""Learning curves from training logs: `mimickit plot` (the reference's `tools/plot_log`).

Reads `log.txt` (a header row of column names, then whitespace-separated rows, one per output
iteration; `# ...` note lines skipped) or `metrics.jsonl` (one JSON object per iteration; NaN and
Infinity tokens read as such; marker rows with an `event` key, e.g. resumes, are not data rows: they
are drawn as dotted vertical lines), or a run folder holding either. Column
names are compared lower-cased, so `Test_Return` (log.txt) and `test_return` (metrics.jsonl) are the
same column. Several runs are overlaid; each chosen column gets its own subplot.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from mimickit.learning.run_folder import EVENT_KEY, LOG_FILE, LOG_NOTE_PREFIX, METRICS_FILE
from mimickit.util.errors import MimicKitError

X_COLUMNS = ("samples", "iteration", "wall_time")
DEFAULT_COLUMNS = ("test_return", "train_return", "test_episode_length", "train_episode_length")
X_LABELS = {"samples": "samples (env steps)", "iteration": "iteration", "wall_time": "wall time (hours)"}
RUN_FILES = (METRICS_FILE, LOG_FILE)  # looked for in this order when a run folder is given
FIG_WIDTH_IN, SUBPLOT_HEIGHT_IN, DPI = 8.0, 2.4, 100

Columns = dict[str, np.ndarray]


def find_log(path: str | Path) -> Path:
    """`path` itself, or the metrics.jsonl / log.txt inside a run folder."""
    p = Path(path)
    if p.is_dir():
        for name in RUN_FILES:
            if (p / name).is_file():
                return p / name
        raise MimicKitError(f"{p}: no {' or '.join(RUN_FILES)} in this folder")
    if not p.is_file():
        raise MimicKitError(f"log file not found: {p}")
    return p


def read_log(path: str | Path) -> Columns:
    """Every numeric column of a log file, lower-cased name → values [rows] (NaN where a row lacks it)."""
    p = find_log(path)
    try:
        text = p.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise MimicKitError(f"{p}: cannot read ({e.__class__.__name__})") from None
    cols = _columns(_read_jsonl(p, text)) if p.suffix == ".jsonl" else _read_table(p, text)
    if not cols or not len(next(iter(cols.values()))):
        raise MimicKitError(f"{p}: no rows")
    return cols


def _read_table(p: Path, text: str) -> Columns:
    # splitlines: "\n" and the reference's "\r"; "# ..." lines are the trainer's notes (why a run stopped)
    note = LOG_NOTE_PREFIX.strip()
    lines = [ln.split() for ln in text.splitlines() if ln.strip() and not ln.startswith(note)]
    if not lines:
        raise MimicKitError(f"{p}: empty file")
    header = [h.lower() for h in lines[0]]
    rows = []
    for num, cells in enumerate(lines[1:], start=2):
        if len(cells) != len(header):
            raise MimicKitError(f"{p}: row {num} has {len(cells)} values, the header has {len(header)} columns")
        try:
            rows.append([float(c) for c in cells])
        except ValueError:
            raise MimicKitError(f"{p}: row {num} is not all numbers (is this a MimicKit log.txt?)") from None
    values = np.array(rows, dtype=np.float64).reshape(len(rows), len(header))
    return {name: values[:, i] for i, name in enumerate(header)}


def read_events(path: str | Path) -> list[dict]:
    """The marker rows (with an `event` key, e.g. resumes) of a metrics.jsonl; none for a log.txt."""
    p = find_log(path)
    if p.suffix != ".jsonl":
        return []
    try:
        text = p.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise MimicKitError(f"{p}: cannot read ({e.__class__.__name__})") from None
    return [row for row in _read_jsonl(p, text) if EVENT_KEY in row]


def _read_jsonl(p: Path, text: str) -> list[dict]:
    """Every JSON object of the file, data and marker rows alike."""
    lines = text.splitlines()
    if lines and not text.endswith("\n"):
        lines = lines[:-1]  # a trainer may be writing the last line right now
    rows = []
    for num, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            row = json.loads(line)
        except ValueError:
            raise MimicKitError(f"{p}: line {num} is not JSON") from None
        if not isinstance(row, dict):
            raise MimicKitError(f"{p}: line {num} is not a JSON object")
        rows.append(row)
    return rows


def _columns(all_rows: list[dict]) -> Columns:
    rows = _current_rows(all_rows)
    names = list(dict.fromkeys(k for row in rows for k in row))
    return {n.lower(): np.array([_number(row.get(n)) for row in rows]) for n in names if _is_numeric(rows, n)}


def _current_rows(all_rows: list[dict]) -> list[dict]:
    """The iteration rows, without those a resume superseded: resuming a diverged run from its model.pt
    re-runs the diverged iteration, so rows before a resume marker from its iteration on are dropped."""
    rows: list[dict] = []
    for row in all_rows:
        if EVENT_KEY not in row:
            rows.append(row)
        elif isinstance(row.get("iteration"), int):
            rows = [r for r in rows if not (isinstance(r.get("iteration"), int) and r["iteration"] >= row["iteration"])]
    return rows


def _is_numeric(rows: list[dict], name: str) -> bool:
    """A column whose values are numbers or missing (older metrics.jsonl files wrote NaN as null, so an
    all-null column is still one); `output` is a flag, kept as 0/1 because it tells which rows hold fresh tests."""
    return all(isinstance(row[name], (int, float)) for row in rows if row.get(name) is not None)


def _number(v: object) -> float:
    return float(v) if isinstance(v, (int, float)) else math.nan


def curve(cols: Columns, x: str, y: str, source: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) points of column `y` against `x`, without the rows where `y` means nothing:
    * metrics.jsonl repeats the last test values on iterations that ran no test (`output` false);
    * a `train_*` / `test_*` statistic of an iteration in which no episode ended is written as 0."""
    for name in (x, y):
        if name not in cols:
            raise MimicKitError(f"{source}: no column {name!r} (columns: {', '.join(cols)})")
    keep = np.isfinite(cols[x]) & np.isfinite(cols[y])
    prefix = y.split("_", 1)[0]
    if prefix == "test" and "output" in cols:
        keep &= cols["output"] > 0
    episodes = f"{prefix}_episodes"
    if prefix in ("train", "test") and y != episodes and episodes in cols:
        keep &= cols[episodes] > 0
    return cols[x][keep], cols[y][keep]


def _draw_events(axes: np.ndarray, events: list[dict], x: str, color: str) -> None:
    """A dotted vertical line in every subplot where the run was resumed."""
    for event in events:
        at = event.get(x)
        if isinstance(at, (int, float)) and math.isfinite(at):
            for ax in axes:
                ax.axvline(at, color=color, linestyle=":", linewidth=1.0, alpha=0.8)


def run_labels(paths: list[Path]) -> list[str]:
    """Legend names: the run folder's name, or the file name where folders repeat."""
    names = [p.parent.name or p.name for p in paths]
    if len(set(names)) < len(names):
        names = [f"{p.parent.name}/{p.name}" if p.parent.name else p.name for p in paths]
    return names


def plot_logs(
    paths: list[str | Path], out: str | Path, x: str = "samples", columns: list[str] | None = None
) -> tuple[int, int]:
    """Write a PNG with one subplot per column, every log overlaid; returns its (width, height) in pixels."""
    import matplotlib

    matplotlib.use("Agg")  # files only: no display on training machines
    import matplotlib.pyplot as plt

    if x not in X_COLUMNS:
        raise MimicKitError(f"--x must be one of {', '.join(X_COLUMNS)}, got {x!r}")
    out = Path(out)
    if out.suffix.lower() != ".png":
        raise MimicKitError(f"--out must be a .png file, got {out}")
    ys = [c.lower() for c in (columns or DEFAULT_COLUMNS)]
    files = [find_log(p) for p in paths]
    # Read and check everything before drawing, so a bad column fails without a half-made figure. A column
    # that only some runs have (AMP has no tracking errors, ADD has) is drawn for those; in none, an error.
    logs = [read_log(f) for f in files]
    events = [read_events(f) for f in files]
    for y in ys:
        if not any(y in cols for cols in logs):
            curve(logs[0], x, y, files[0] if len(files) == 1 else ", ".join(map(str, files)))  # raises
    curves = [[curve(cols, x, y, f) if y in cols else None for y in ys] for f, cols in zip(files, logs, strict=True)]
    fig, axes = plt.subplots(
        len(ys), 1, sharex=True, squeeze=False, figsize=(FIG_WIDTH_IN, SUBPLOT_HEIGHT_IN * len(ys)), dpi=DPI
    )
    try:
        handles = {}
        for i, (label, run) in enumerate(zip(run_labels(files), curves, strict=True)):
            for ax, points in zip(axes[:, 0], run, strict=True):
                if points is not None:  # the run's colour stays its own in every subplot
                    (handles[label],) = ax.plot(*points, label=label, linewidth=1.2, color=f"C{i % 10}")
            _draw_events(axes[:, 0], events[i], x, f"C{i % 10}")
        for ax, y in zip(axes[:, 0], ys, strict=True):
            ax.set_ylabel(y)
            ax.grid(alpha=0.3)
        axes[0, 0].legend(handles.values(), handles.keys(), fontsize="small")
        axes[-1, 0].set_xlabel(X_LABELS[x])
        fig.tight_layout()
        out.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out, dpi=DPI)
        w, h = fig.canvas.get_width_height()
    finally:
        plt.close(fig)
    return w, h
