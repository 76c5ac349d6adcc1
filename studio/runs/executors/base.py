"""The one interface the run manager drives its runs' processes through.

A run's process is a *job*: the executor starts it (`submit` returns its id, which the registry
keeps), reports on it (`status`: pending / running / ended, with times and exit code), stops it
(SIGTERM, so the trainer writes its checkpoint, then SIGKILL after the executor's grace period) and
gives its output (`logs`). A job outlives the server: a new server asks `status` of the job ids the
registry holds and keeps the ones still going (re-attach). An executor that `queues` (Ray) takes
every run at once and starts each when its resources are free; otherwise the run manager keeps
the queue and submits at most `--max-concurrent-runs` at a time.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import Protocol

EXECUTORS = ("local", "ray")


class JobState(str, Enum):
    PENDING = "pending"  # submitted, waiting for resources
    RUNNING = "running"
    ENDED = "ended"  # exited (any way); the run folder's state.json says how


@dataclass
class Job:
    """What an executor knows of one job; times are Unix seconds."""

    state: JobState
    started_at: float | None = None
    ended_at: float | None = None
    exit_code: int | None = None  # None: unknown (not ended, or a process this server did not start)
    message: str | None = None  # the executor's own line about it (e.g. Ray's reason for a failed start)


@dataclass
class Launch:
    """One process to start: its argv, the folder it works in and writes to, its extra environment
    and the resources it asks for (only an executor that schedules, Ray, uses them)."""

    argv: list[str]
    work_dir: Path
    console_file: Path
    env: dict[str, str] = field(default_factory=dict)
    num_cpus: float | None = None
    num_gpus: float | None = None
    name: str = ""


class Executor(Protocol):
    name: str
    queues: bool

    def submit(self, launch: Launch) -> str:
        """Start (or queue) the process; its job id. OSError/RuntimeError when it cannot be submitted."""
        ...

    def status(self, job_id: str, argv_hint: str = "") -> Job | None:
        """The job's state; None when the executor does not know it (gone with a previous server, or
        not what `argv_hint`, a string its command line contains, says it should be)."""
        ...

    def stop(self, job_id: str) -> None:
        """SIGTERM the job's processes (the trainer checkpoints), SIGKILL them after the grace period."""
        ...

    def logs(self, job_id: str) -> str | None:
        """Its output so far, or None when the executor keeps none (a local job writes console.log)."""
        ...

    def close(self) -> None: ...
