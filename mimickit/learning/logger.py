"""Training output: terminal table, `log.txt`, `metrics.jsonl`, TensorBoard (log.txt and tags as the reference's).

Per iteration the agent calls `log(key, value, collection, quiet)` for each scalar (and `log_metric`
for per-term means that only go to metrics.jsonl and TensorBoard), then:
* `print_log()`: averages every entry over processes (ints stay ints; all ranks must call it) and
  prints the table of non-quiet entries (rank 0), above a tqdm bar when stdout is a terminal;
* `write_metrics(output)`: one JSON object per iteration to `metrics.jsonl`, flushed at once so a
  studio can tail it: every entry under its lower-cased key (`Train_Return` → `train_return`,
  `Wall_Time` → `wall_time` in hours, as the text log), the `log_metric` entries (`reward_terms.<name>`,
  `tracking.<name>`), `output` (whether this iteration ran the test episodes; otherwise the test
  values are the previous ones) and `time` (unix seconds). A NaN or infinite value stays one
  (Python json's `NaN` / `Infinity` / `-Infinity` tokens), so a diverged run's curves show it;
* `write_event(row)`: a marker row, e.g. a resume (`mimickit.learning.run_folder.resume_row`); it has an
  `event` key and no metric columns, so readers tell it from iteration rows;
* `write_note(line)`: a `# line` in log.txt (a comment to numpy.genfromtxt and `mimickit plot`);
* `write_log()` on output iterations: a row of `log.txt` in the reference's columns (header of all
  keys on the first call, each value's `str()` left-justified to 25 characters) and, for
  `logger_type` "tb", TensorBoard scalars `<collection>/<key>` at step `Samples`.
Deviation: rows end with "\\n" where the reference writes "\\r"; readers that open the file with
universal newlines (numpy.genfromtxt, the reference plot tool) read both.
Only rank 0 writes files. `append=True` (a resumed run) appends to existing files and keeps the
existing log.txt columns.
"""

from __future__ import annotations

import contextlib
import json
import math
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import torch
from tqdm import tqdm

from mimickit.learning import mp_util
from mimickit.learning.run_folder import LOG_FILE, LOG_NOTE_PREFIX, METRICS_FILE
from mimickit.util.errors import MimicKitError

LOGGER_TYPES = ("txt", "tb", "wandb")
_COL_WIDTH = 25
_VAL_WIDTH = 15


@dataclass
class _Entry:
    val: float | int
    collection: str
    quiet: bool


class Logger:
    def __init__(
        self,
        out_dir: str | Path,
        logger_type: str = "txt",
        append: bool = False,
        max_samples: int | None = None,
        run_config: dict[str, Any] | None = None,
        step_key: str = "Samples",
    ) -> None:
        if logger_type not in LOGGER_TYPES:
            raise MimicKitError(f"unknown logger '{logger_type}'; choose one of {', '.join(LOGGER_TYPES)}")
        self._out_dir = Path(out_dir)
        self._root = mp_util.is_root_proc()
        self._step_key = step_key
        self._entries: dict[str, _Entry] = {}
        self._metrics: dict[str, float] = {}
        self._header: list[str] | None = None
        self._log_file = None
        self._metrics_file = None
        self._tb = None
        self._wandb = None
        self._bar: tqdm | None = None
        if self._root:
            self._open_files(append, logger_type, run_config)
            if sys.stdout.isatty():
                total = max_samples if max_samples is not None and max_samples < 2**62 else None
                self._bar = tqdm(total=total, unit="samples", unit_scale=True, dynamic_ncols=True, leave=True)

    def log(self, key: str, val: float | int | torch.Tensor, collection: str = "Misc", quiet: bool = False) -> None:
        """Set this iteration's value of `key` (a value not logged again keeps its previous value)."""
        if isinstance(val, torch.Tensor):
            val = val.item()
        self._entries[key] = _Entry(val, collection, quiet)

    def log_metric(self, name: str, val: float | torch.Tensor) -> None:
        """A value for metrics.jsonl and TensorBoard only (e.g. `reward_terms.pose`)."""
        self._metrics[name] = float(val.item() if isinstance(val, torch.Tensor) else val)

    def get(self, key: str) -> float | int | None:
        entry = self._entries.get(key)
        return entry.val if entry is not None else None

    def print_log(self) -> None:
        """Average entries over processes, then print the table (rank 0)."""
        self._reduce_over_procs()
        if not self._root:
            return
        shown = [(k, e.val) for k, e in self._entries.items() if not e.quiet]
        if not shown:
            return
        width = max(len(k) for k, _ in shown)
        dashes = "-" * (22 + width)
        lines = [dashes] + [f"| {k.rjust(width)} | {_format_val(v).rjust(_VAL_WIDTH)} |" for k, v in shown] + [dashes]
        self._print("\n".join(lines))
        if self._bar is not None and self.get(self._step_key) is not None:
            self._bar.n = int(self.get(self._step_key) or 0)
            self._bar.refresh()

    def write_metrics(self, output: bool) -> None:
        """Append this iteration's JSON line to metrics.jsonl (rank 0)."""
        if self._root and self._metrics_file is not None:
            row: dict[str, Any] = {k.lower(): e.val for k, e in self._entries.items()}
            row.update(self._metrics)
            row["output"] = output
            row["time"] = time.time()
            self._write_row(row)

    def write_event(self, row: dict[str, Any]) -> None:
        """Append a marker row (with an `event` key) to metrics.jsonl (rank 0)."""
        if self._root and self._metrics_file is not None:
            self._write_row(row)

    def write_note(self, line: str) -> None:
        """Append `# line` to log.txt (rank 0): a note between the table's rows, e.g. why training stopped."""
        if self._root and self._log_file is not None:
            with _naming(self._log_file):
                self._log_file.write(f"{LOG_NOTE_PREFIX}{line}\n")
                self._log_file.flush()

    def _write_row(self, row: dict[str, Any]) -> None:
        assert self._metrics_file is not None
        with _naming(self._metrics_file):
            self._metrics_file.write(json.dumps(row) + "\n")  # allow_nan: NaN stays NaN
            self._metrics_file.flush()

    def write_log(self) -> None:
        """Write a log.txt row (header first) and the TensorBoard / wandb scalars (rank 0)."""
        if not self._root:
            return
        if self._log_file is not None:
            with _naming(self._log_file):
                if self._header is None:
                    self._header = list(self._entries)
                    self._log_file.write(_row(self._header))
                values = [self._entries[k].val if k in self._entries else math.nan for k in self._header]
                self._log_file.write(_row(values))
                self._log_file.flush()
        step = int(self.get(self._step_key) or 0)
        scalars = {f"{e.collection}/{k}": e.val for k, e in self._entries.items()}
        scalars.update({f"{_metric_collection(k)}/{k}": v for k, v in self._metrics.items()})
        if self._tb is not None:
            for tag, v in scalars.items():
                self._tb.add_scalar(tag, v, global_step=step)
            self._tb.flush()
        if self._wandb is not None:
            self._wandb.log(scalars, step=step)

    def print(self, msg: str) -> None:
        """A line on the terminal from rank 0 (above the progress bar)."""
        if self._root:
            self._print(msg)

    def close(self) -> None:
        files = [f for f in (self._log_file, self._metrics_file) if f is not None]
        self._log_file = self._metrics_file = None
        if self._tb is not None:
            self._tb.close()
            self._tb = None
        if self._wandb is not None:
            self._wandb.finish()
            self._wandb = None
        if self._bar is not None:
            self._bar.close()
            self._bar = None
        with contextlib.ExitStack() as closing:  # every file closed, even when one cannot flush (a full disk)
            for f in files:
                closing.callback(_close_named, f)

    def _open_files(self, append: bool, logger_type: str, run_config: dict[str, Any] | None) -> None:
        self._out_dir.mkdir(parents=True, exist_ok=True)
        log_path = self._out_dir / LOG_FILE
        if append and log_path.is_file():
            self._header = _read_header(log_path)
        self._log_file = open(log_path, "a" if append else "w")  # noqa: SIM115 - kept open for the run
        self._metrics_file = open(self._out_dir / METRICS_FILE, "a" if append else "w")  # noqa: SIM115
        if logger_type == "tb":
            from torch.utils.tensorboard import SummaryWriter

            self._tb = SummaryWriter(log_dir=str(self._out_dir))
        elif logger_type == "wandb":
            try:
                import wandb
            except ImportError:
                raise MimicKitError("--logger wandb needs the wandb package (pip install wandb)") from None
            self._wandb = wandb.init(project="mimickit", name=self._out_dir.name, config=run_config or {})

    def _reduce_over_procs(self) -> None:
        if not mp_util.enable_mp():
            return
        keys = list(self._entries)
        flat = [float(self._entries[k].val) for k in keys] + list(self._metrics.values())
        vals = torch.tensor(flat, dtype=torch.float64, device=mp_util.get_device())
        vals = mp_util.reduce_mean(vals).cpu().tolist()
        for k, v in zip(keys, vals, strict=False):
            e = self._entries[k]
            e.val = int(round(v)) if isinstance(e.val, int) else v
        self._metrics = dict(zip(self._metrics, vals[len(keys) :], strict=True))

    def _print(self, msg: str) -> None:
        if self._bar is not None:
            self._bar.write(msg)
        else:
            print(msg, flush=True)


@contextlib.contextmanager
def _naming(f: IO[str]) -> Iterator[None]:
    """An OS error while writing `f` names its file (a full disk's error at a flush names none)."""
    try:
        yield
    except OSError as e:
        if e.filename is not None:
            raise
        raise OSError(e.errno, e.strerror, f.name) from e


def _close_named(f: IO[str]) -> None:
    with _naming(f):
        f.close()


def _read_header(log_path: Path) -> list[str] | None:
    """The column names of an existing log.txt: its first line that is not a note."""
    with open(log_path, newline=None) as f:
        for line in f:
            if line.strip() and not line.startswith(LOG_NOTE_PREFIX.strip()):
                return line.split()
    return None


def _format_val(v: float | int) -> str:
    return str(v) if isinstance(v, int) else f"{v:8.3g}"


def _row(vals: list[Any]) -> str:
    cells = [str(v) for v in vals]
    return "".join(c.ljust(_COL_WIDTH) if len(c) < _COL_WIDTH else c + " " for c in cells).rstrip() + "\n"


def _metric_collection(name: str) -> str:
    return {"reward_terms": "3_Reward_Terms", "tracking": "4_Tracking"}.get(name.split(".")[0], "Misc")
