"""Where a run's checkpoints sit in its training: the iteration and samples of its `model.pt` and of each
`int_models/model_N.pt` (`--save_int_models`), for the checkpoint list, without loading any checkpoint (a
list request may see hundreds of them).

Iterations are counted as a checkpoint's `_train_state` counts them, which is what a rollout's label and
the inspection show: the iterations its weights have trained. The trainer names an intermediate
checkpoint after the index of the iteration that wrote it (`model_0000000004.pt` after iteration 4, the
fifth), so its count is N + 1, and its samples are those of metrics.jsonl's row of iteration N.
`model.pt` is the last output iteration's while a run trains; a run that ended records its model's
iteration and samples in state.json (a stop or a divergence writes model.pt off the output iterations).
"""

from __future__ import annotations

import json
import re
import threading
from dataclasses import dataclass, field
from pathlib import Path

from mimickit.learning.run_folder import EndState, RunFolder

INT_MODEL_RE = re.compile(r"^model_(\d{1,18})\.pt$")
OUTPUT_MARK = b'"output": true'  # how the trainer's json.dumps writes an output row's flag
ENDED = (EndState.FINISHED, EndState.STOPPED, EndState.DIVERGED)  # their state.json holds model.pt's point
MAX_CACHED = 4096
BLOCK = 1 << 20


@dataclass
class OutputRows:
    """The output rows of one metrics.jsonl read so far (the iterations that wrote checkpoints)."""

    file_id: tuple[int, int]  # (device, inode): a replaced file is read again from its start
    pos: int = 0  # bytes read: the complete lines before it
    samples: dict[int, int] = field(default_factory=dict)  # iteration index -> samples after it
    last: int | None = None  # the last output row's iteration index


_cache: dict[str, OutputRows] = {}
_lock = threading.Lock()


def output_rows(metrics_file: Path) -> OutputRows | None:
    """The file's output rows, read on from where the last call stopped: a list request polled every few
    seconds reads only what the trainers appended since. None when there is no such file."""
    try:
        st = metrics_file.stat()
    except OSError:
        return None
    key = str(metrics_file)
    with _lock:
        seen = _cache.get(key)
        if seen is None or seen.file_id != (st.st_dev, st.st_ino) or st.st_size < seen.pos:
            seen = OutputRows((st.st_dev, st.st_ino))
        if st.st_size > seen.pos:
            _read_on(metrics_file, seen)
        if len(_cache) >= MAX_CACHED and key not in _cache:
            _cache.clear()  # deleted runs' entries: dropped wholesale, the live ones are read again once
        _cache[key] = seen
        return seen


def _read_on(metrics_file: Path, seen: OutputRows) -> None:
    """The complete lines after `seen.pos`, a block at a time (a long run's file is not held in memory);
    a half-written last line is read on the next call."""
    try:
        with metrics_file.open("rb") as f:
            f.seek(seen.pos)
            rest = b""
            while block := f.read(BLOCK):
                *lines, rest = (rest + block).split(b"\n")
                seen.pos += sum(len(line) + 1 for line in lines)
                for line in lines:
                    _take(line, seen)
                if len(rest) > BLOCK:  # no row is this long: skipped, not held
                    seen.pos += len(rest)
                    rest = b""
    except OSError:
        return


def _take(line: bytes, seen: OutputRows) -> None:
    if OUTPUT_MARK not in line:  # most rows are not output rows: not parsed
        return
    try:
        row = json.loads(line)
        iteration, samples = int(row["iteration"]), int(row["samples"])
    except (ValueError, KeyError, TypeError, OverflowError):
        return  # a corrupt row is skipped, as the curves skip it
    seen.samples[iteration] = samples  # a resume that repeats an iteration: the newer row wins
    seen.last = iteration


def int_model_index(path: Path) -> int | None:
    """N of `int_models/model_N.pt` (the index of the iteration that wrote it); None for another name."""
    m = INT_MODEL_RE.match(path.name)
    return int(m.group(1)) if m else None


@dataclass(frozen=True)
class RunHistory:
    """What one run folder says about its checkpoints' places in training."""

    model: tuple[int | None, int | None]  # model.pt's (iteration, samples)
    outputs: OutputRows | None

    def int_model(self, index: int) -> tuple[int, int | None]:
        """(iteration, samples) of `int_models/model_{index}.pt`."""
        samples = self.outputs.samples.get(index) if self.outputs else None
        return index + 1, samples


def run_history(run_dir: Path) -> RunHistory:
    folder = RunFolder(run_dir)
    outputs = output_rows(folder.metrics_file)
    state = folder.read_state()
    if state is not None and state.state in ENDED and state.iteration > 0:
        model: tuple[int | None, int | None] = (state.iteration, state.samples)
    elif outputs is not None and outputs.last is not None:
        model = (outputs.last + 1, outputs.samples[outputs.last])
    else:
        model = (None, None)
    return RunHistory(model, outputs)
