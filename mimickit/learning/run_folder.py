"""The run folder: which files a training run writes, under which names, and how its end is recorded.

The trainer (`mimickit/run.py`, the agent's logger and checkpoints) and the studio both go through
this module, so a name is spelt once. A run folder holds:

    args.json            the resolved argv, every effective value, the seed used, versions (`write_args`)
    engine_config.yaml   the configs as trained (`--motion_file` applied to env_config.yaml)
    env_config.yaml
    agent_config.yaml
    log.txt              the reference's text log, one row per output iteration; `# ...` note lines
                         (e.g. why a run diverged) are comments to numpy.genfromtxt and `mimickit plot`
    metrics.jsonl        one JSON object per iteration (NaN/inf kept as json's NaN/Infinity tokens), plus
                         one marker row per resume (`resume_row`; rows with an `event` key hold no metrics)
    model.pt             the newest finite checkpoint
    int_models/          model_{iteration:010d}.pt with --save_int_models
    console.log          stdout and stderr, written by whoever launched the trainer (the studio)
    state.json           the run's state: running, then finished / stopped / diverged / failed with
                         the line that says why (`write_state`; on a full disk, over the old file)

The trainer's exit code says the same as the end state (`ExitCode`): 0 finished or stopped, 1 failed
after the run started, 2 refused before anything started (one `error:` line, the folder untouched),
3 diverged.
"""

from __future__ import annotations

import errno
import json
import os
import time
from dataclasses import asdict, dataclass, field
from enum import Enum, IntEnum
from pathlib import Path
from typing import Any

from mimickit.util.paths import atomic_write_bytes

ARGS_FILE = "args.json"
ENGINE_CONFIG_FILE = "engine_config.yaml"
ENV_CONFIG_FILE = "env_config.yaml"
AGENT_CONFIG_FILE = "agent_config.yaml"
LOG_FILE = "log.txt"
METRICS_FILE = "metrics.jsonl"
MODEL_FILE = "model.pt"
INT_MODELS_DIR = "int_models"
CONSOLE_FILE = "console.log"
STATE_FILE = "state.json"
LOG_NOTE_PREFIX = "# "
EVENT_KEY = "event"
RESUME_EVENT = "resume"
ARGS_FORMAT = 1
NO_SPACE_ERRNOS = (errno.ENOSPC, errno.EDQUOT)
"""A disk that is full or over quota: what `RunFolder.write_state` works around."""


class ExitCode(IntEnum):
    OK = 0  # finished or stopped
    FAILED = 1  # an error after the run started (state failed)
    REFUSED = 2  # bad input: nothing started, nothing written
    DIVERGED = 3


class EndState(str, Enum):
    RUNNING = "running"
    FINISHED = "finished"  # reached its max_samples
    STOPPED = "stopped"  # SIGTERM / Ctrl-C: a checkpoint was saved, the run can resume
    DIVERGED = "diverged"  # a non-finite loss, gradient, weight, observation or action
    FAILED = "failed"  # an error ended it


@dataclass
class RunState:
    state: EndState
    reason: str = ""
    iteration: int = 0
    samples: int = 0
    updated_at: float = field(default_factory=time.time)

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "state": self.state.value}


def int_model_name(iteration: int) -> str:
    return f"model_{iteration:010d}.pt"


def resume_row(iteration: int, samples: int, wall_time_hours: float, max_samples: int | None) -> dict[str, Any]:
    """metrics.jsonl's marker of a resume: where the run continues from, and its new budget
    (`max_samples` None: no limit)."""
    budget = max_samples if max_samples is not None and max_samples < 2**62 else None
    return {
        EVENT_KEY: RESUME_EVENT,
        "iteration": int(iteration),
        "samples": int(samples),
        "wall_time": float(wall_time_hours),
        "max_samples": budget,
        "time": time.time(),
    }


def is_event_row(row: dict[str, Any]) -> bool:
    """A marker row of metrics.jsonl (not an iteration's metrics)."""
    return EVENT_KEY in row


class RunFolder:
    """One run's folder; the paths of its files and its two JSON records."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)

    def __repr__(self) -> str:
        return f"RunFolder({str(self.path)!r})"

    def file(self, name: str) -> Path:
        return self.path / name

    @property
    def args_file(self) -> Path:
        return self.path / ARGS_FILE

    @property
    def log_file(self) -> Path:
        return self.path / LOG_FILE

    @property
    def metrics_file(self) -> Path:
        return self.path / METRICS_FILE

    @property
    def model_file(self) -> Path:
        return self.path / MODEL_FILE

    @property
    def int_models_dir(self) -> Path:
        return self.path / INT_MODELS_DIR

    @property
    def console_file(self) -> Path:
        return self.path / CONSOLE_FILE

    @property
    def state_file(self) -> Path:
        return self.path / STATE_FILE

    def config_file(self, role: str) -> Path:
        """`role` is engine, env or agent."""
        names = {"engine": ENGINE_CONFIG_FILE, "env": ENV_CONFIG_FILE, "agent": AGENT_CONFIG_FILE}
        if role not in names:
            raise ValueError(f"unknown config role {role!r}; expected one of {sorted(names)}")
        return self.path / names[role]

    def write_args(self, record: dict[str, Any]) -> None:
        write_json_atomic(self.args_file, record)

    def read_args(self) -> dict[str, Any] | None:
        return _read_json(self.args_file)

    def write_state(self, state: EndState, reason: str = "", *, iteration: int = 0, samples: int = 0) -> None:
        """state.json, atomically; on a full disk, over the old file in the space it already holds (a
        state is a few hundred bytes), so a run that failed for want of space still says so."""
        data = _json_bytes(RunState(state, reason, iteration, samples).to_dict())
        try:
            atomic_write_bytes(self.state_file, data)
        except OSError as e:
            if e.errno not in NO_SPACE_ERRNOS or not overwrite_in_place(self.state_file, data):
                raise

    def read_state(self) -> RunState | None:
        """The recorded state, or None when there is none (or it cannot be read)."""
        data = _read_json(self.state_file)
        if not data:
            return None
        try:
            return RunState(
                EndState(data["state"]),
                str(data.get("reason", "")),
                int(data.get("iteration", 0)),
                int(data.get("samples", 0)),
                float(data.get("updated_at", 0.0)),
            )
        except (KeyError, ValueError, TypeError):
            return None


def write_json_atomic(path: Path, obj: Any) -> None:
    """Write `obj` as JSON so that a reader never sees half a file."""
    atomic_write_bytes(path, _json_bytes(obj))


def _json_bytes(obj: Any) -> bytes:
    return (json.dumps(obj, indent=1) + "\n").encode()


def overwrite_in_place(path: Path, data: bytes) -> bool:
    """Replace the content of an existing file with `data` when it fits in the disk space the file
    already holds (needs no new space: works on a full disk); False when it does not fit or there is
    no such file. Not atomic: the last resort of a small record that must say why a run ended."""
    try:
        held = path.stat().st_blocks * 512
    except OSError:
        return False
    if len(data) > held:
        return False
    with open(path, "r+b") as f:
        f.write(data)
        f.truncate()
        f.flush()
        os.fsync(f.fileno())
    return True


def _read_json(path: Path) -> dict[str, Any] | None:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None
