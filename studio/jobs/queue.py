"""The queue every kind of background job (evals, videos) shares: jobs run one at a time by one worker
thread, each a `mimickit` subprocess in its own folder `<root>/<id>-<time>-<random>/` and its own session
(process group), so that `stop`, the time limit and the server's exit reach it and anything it started.
A job's process also dies with the server, even with one killed by `kill -9` (the parent-death signal,
as the local executor's trainers). A job folder is made new (an exclusive `mkdir`, owner-only, under an
unguessable name): nothing planted at its name beforehand, such as a symlink, is written through. At most
`max_queued` jobs wait at once; one more is refused.

A kind is a small spec on this queue: its job's request and result fields (a `Job` dataclass), its
folder under the runs folder, its command line (`_argv`) and how it reads its result (`_result`). The
command's output goes to `console.log` in the job's folder (its stdout to `stdout_file` when the kind
reads a report from it); a job that fails says why in one line: `mimickit`'s own `error:` line, else
the last line it printed.

Each job keeps a small record, `job.json` in its folder (written atomically whenever the job changes:
its request, status, times, command, result and failure line). A new queue lists the jobs of those
records, so a restarted server shows the jobs of the one before. A job that was queued or running when
its server died (`kill -9`, a crash) is listed as failed with a line saying the server stopped while it
ran, and its process group, if it still runs, is killed; a server that stops cleanly marks its own
active jobs the same way. Ids are never reused: `<root>/next_id` keeps the next one across restarts and
deletions, and a queue starts after the highest id it finds either there or in a folder name.
"""

from __future__ import annotations

import atexit
import contextlib
import json
import logging
import os
import queue
import re
import secrets
import shutil
import signal
import subprocess
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import IO, Any, ClassVar, Generic, TypeVar

from mimickit.util.errors import MimicKitError
from mimickit.util.paths import atomic_write_bytes
from studio.child import start_child
from studio.jobs.process import failure_line, kill_group
from studio.library import one_line
from studio.runs.manager import RunError, child_env
from studio.settings import Settings

LOG = logging.getLogger("studio")
RECORD_FILE = "job.json"
CONSOLE_FILE = "console.log"
NEXT_ID_FILE = "next_id"
MAX_RECORD_BYTES = 32 * 1024 * 1024  # a record is a few kB; a dataset of thousands of clips, a few MB
ACTIVE = ("queued", "running")
STATUSES = (*ACTIVE, "finished", "failed", "stopped")
_FOLDER = re.compile(r"(\d+)-")


def write_arg_file(path: Path, configs: dict[str, Any]) -> Path:
    """An arg file at `path` naming `configs` (`--key value` lines; a None value is left out), for a job's
    `mimickit` command."""
    path.write_text("".join(f"--{k} {v}\n" for k, v in configs.items() if v is not None))
    return path


def server_stopped_line(status: str) -> str:
    """The failure line of a job the server stopped with (queued or running)."""
    if status == "running":
        return "the server stopped while the job ran; it did not finish"
    return "the server stopped while the job was queued; it never ran"


@dataclass(kw_only=True)
class Job:
    """What every job has; a kind adds its request and result fields and `to_json`."""

    PATH_FIELDS: ClassVar[tuple[str, ...]] = ("folder",)
    """Fields holding a `Path` (or None): strings in the record."""

    id: int
    folder: Path
    status: str = "queued"  # queued, running, then finished, failed or stopped
    error: str | None = None
    command: list[str] = field(default_factory=list)
    created_at: float = field(default_factory=time.time)
    started_at: float | None = None
    ended_at: float | None = None
    pid: int | None = None  # the process (its group's leader) while it runs: a restart kills an orphan

    def to_json(self) -> dict[str, Any]:
        """What the API shows of every job; a kind adds its own fields."""
        return {
            "id": self.id,
            "status": self.status,
            "error": self.error,
            "folder": str(self.folder),
            "command": self.command,
            "created_at": self.created_at,
            "started_at": self.started_at,
            "ended_at": self.ended_at,
        }

    def to_record(self) -> dict[str, Any]:
        return {f.name: _plain(getattr(self, f.name)) for f in fields(self)}

    @classmethod
    def from_record(cls, data: dict[str, Any]) -> Job:
        """The job of a record; ValueError/TypeError/KeyError when it is not one of this kind."""
        if not isinstance(data, dict):
            raise TypeError(f"a record is a JSON object, got {type(data).__name__}")
        values = {f.name: data[f.name] for f in fields(cls) if f.name in data}
        for name in cls.PATH_FIELDS:
            if values.get(name) is not None:
                values[name] = Path(values[name])
        job = cls(**values)
        if not isinstance(job.id, int) or job.status not in STATUSES:
            raise ValueError(f"id {job.id!r}, status {job.status!r}")
        return job


def _plain(value: Any) -> Any:
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value


class JobFailed(Exception):
    """A job whose command exited 0 without a usable result: its one failure line."""


J = TypeVar("J", bound=Job)


class JobQueue(Generic[J]):
    """The jobs of one kind under `<runs-dir>/<folder_name>/` and the worker thread that runs them. A
    kind sets the class attributes below and implements `_argv(job)` and `_result(job)`."""

    job_type: type[J]
    kind = "background"  # what its lines call a job: "eval", "video"
    folder_name = "jobs"  # its folder under the runs folder
    program = "mimickit"  # what its failure lines call the command: "mimickit eval"
    default_command: ClassVar[list[str]] = []
    stdout_file: str | None = None  # where the command's stdout goes when the kind reads it (else console.log)
    cannot_run = "could not run the job"  # the start of the line for an exception while a job runs

    def __init__(self, settings: Settings, command: list[str] | None = None, time_limit_s: float | None = None) -> None:
        self.settings = settings
        self.command = list(command or self.default_command)
        self.root = settings.runs_dir / self.folder_name
        self.max_queued = settings.max_queued_jobs
        self.time_limit_s = self._time_limit(settings) if time_limit_s is None else time_limit_s
        self._jobs: dict[int, J] = {}
        self._lock = threading.Lock()
        self._queue: queue.Queue[J | None] = queue.Queue()
        self._proc: subprocess.Popen[bytes] | None = None  # the running job's, set and read under the lock
        self._closed = False
        self.on_change: Callable[[], None] = _nothing  # called (under the queue's lock) after each change
        self._next_id = self._recover()
        self._thread = threading.Thread(target=self._work, name=self.folder_name, daemon=True)
        self._thread.start()
        atexit.register(self.close)  # a server that exits leaves no job running

    def get(self, job_id: int) -> J | None:
        with self._lock:
            return self._jobs.get(job_id)

    def list(self) -> list[J]:
        with self._lock:
            return sorted(self._jobs.values(), key=lambda j: -j.id)

    def stop(self, job_id: int) -> bool:
        """Stop a queued job (it will not start) or a running one (its process group killed): status
        `stopped`. False when the job had already ended."""
        with self._lock:
            job = self._jobs.get(job_id)
            if job is None or job.status not in ACTIVE:
                return False
            running, proc = job.status == "running", self._proc
            self._set(job, "stopped", None)
        if running and proc is not None:
            kill_group(proc)
        return True

    def remove(self, job_id: int) -> bool:
        """Forget an ended job and delete its folder. False while it is queued or running."""
        with self._lock:
            job = self._jobs.get(job_id)
            if job is None or job.status in ACTIVE:
                return False
            del self._jobs[job_id]
            self.on_change()
        shutil.rmtree(job.folder, ignore_errors=True)  # a folder a server made under `root`
        return True

    def close(self) -> None:
        """Stop the worker: the active jobs end as failed (the server stopped), a running one's process
        group is killed."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            proc = self._proc
            for job in self._jobs.values():
                if job.status in ACTIVE:
                    self._set(job, "failed", server_stopped_line(job.status))
        if proc is not None:
            kill_group(proc)
        self._queue.put(None)
        self._thread.join(timeout=5)

    # -- for the kinds -----------------------------------------------------------------------------

    def _time_limit(self, settings: Settings) -> float:
        raise NotImplementedError

    def _argv(self, job: J) -> list[str]:
        """The job's command line (written into its folder, such as an arg file, when it needs one)."""
        raise NotImplementedError

    def _result(self, job: J) -> dict[str, Any]:
        """The result fields of a job whose command exited 0; JobFailed when there is none."""
        raise NotImplementedError

    def _add(self, make: Callable[[int, Path], J]) -> J:
        """A new job, `make(id, folder)` with its command, recorded and queued; RunError (429) past
        `max_queued`."""
        with self._lock:
            if self._closed:
                raise MimicKitError("the server is stopping: no new jobs")
            queued = sum(j.status == "queued" for j in self._jobs.values())
            if queued >= self.max_queued:
                raise RunError(
                    f"{queued} {self.kind} jobs are already queued, the most the server takes "
                    "(--max-queued-jobs); wait for them or stop some",
                    429,
                )
            self._check_root()
            job_id = self._next_id
            self._next_id += 1
            atomic_write_bytes(self.root / NEXT_ID_FILE, f"{self._next_id}\n".encode())
            folder = self._new_folder(job_id)
            job = make(job_id, folder)
            job.command = self._argv(job)
            self._jobs[job_id] = job
            self._save(job)
        self._queue.put(job)
        return job

    def _check_root(self) -> None:
        """The queue's root, made if needed: a real folder, not a symlink leading elsewhere."""
        self.root.mkdir(parents=True, exist_ok=True)
        if self.root.is_symlink():
            raise MimicKitError(f"{self.root} is a symlink; the job folders must be a real folder")

    def _new_folder(self, job_id: int) -> Path:
        """A job folder made now, owner-only, under a name nobody could guess and plant a link at
        beforehand."""
        folder = self.root / f"{job_id:04d}-{int(time.time())}-{secrets.token_hex(4)}"
        try:
            folder.mkdir(mode=0o700)  # exclusive: a name taken already (a file, a link) is an error
        except FileExistsError:
            raise MimicKitError(f"{folder} already exists; not writing a job into it") from None
        return folder

    # -- inside -----------------------------------------------------------------------------------

    def _run(self, job: J) -> None:
        console = job.folder / CONSOLE_FILE
        with contextlib.ExitStack() as files:
            err = files.enter_context(open(console, "wb"))
            out = files.enter_context(open(job.folder / self.stdout_file, "wb")) if self.stdout_file else None
            proc = self._launch(job, out or err, err if out else subprocess.STDOUT)
            if proc is None:
                return
            code = self._wait(proc)
        if job.status != "running":  # stopped meanwhile
            return
        if code is None:
            self._end(job, "failed", f"{self.program} took longer than {self.time_limit_s:g} s and was stopped")
        elif code != 0:
            self._end(job, "failed", failure_line(self.program, console, code))
        else:
            try:
                result = self._result(job)
            except JobFailed as e:
                self._end(job, "failed", one_line(str(e)))
                return
            self._end(job, "finished", **result)

    def _launch(self, job: J, stdout: IO[bytes], stderr: IO[bytes] | int) -> subprocess.Popen[bytes] | None:
        """Start the job's command in its folder and session; None when it was stopped meanwhile (a
        `stop` either comes first and the job never starts, or it sees the process)."""
        with self._lock:
            if job.status != "queued" or self._closed:
                return None
            # Its own process group (`stop`, the time limit and `close` reach its children), ended by
            # the kernel when this worker thread dies (`kill -9` of the server too).
            self._proc = proc = start_child(
                job.command, cwd=job.folder, env={**os.environ, **child_env()}, stdout=stdout, stderr=stderr
            )
            job.status, job.started_at, job.pid = "running", time.time(), proc.pid
            self._save(job)
        return proc

    def _wait(self, proc: subprocess.Popen[bytes]) -> int | None:
        """The exit code; None when it ran past `time_limit_s` (its process group is then killed)."""
        try:
            code: int | None = proc.wait(timeout=self.time_limit_s)
        except subprocess.TimeoutExpired:
            kill_group(proc)
            proc.wait()
            code = None
        with self._lock:
            self._proc = None
        return code

    def _end(self, job: J, status: str, error: str | None = None, **result: Any) -> None:
        """The job's end, with `result` fields set; a job that has already ended (stopped, or the server
        stopping) stays as it is."""
        with self._lock:
            if job.status not in ACTIVE:
                return
            for name, value in result.items():
                setattr(job, name, value)
            self._set(job, status, error)

    def _work(self) -> None:
        while True:
            job = self._queue.get()
            if job is None or self._closed:
                return
            if job.status != "queued":  # stopped while it waited
                continue
            try:
                self._run(job)
            except Exception as e:  # noqa: BLE001 - a job that cannot run is a failed job, not a dead worker
                self._end(job, "failed", one_line(f"{self.cannot_run}: {type(e).__name__}: {e}"))

    def _set(self, job: J, status: str, error: str | None) -> None:
        """Under the lock: the job's new status, recorded."""
        job.status, job.error, job.ended_at = status, error, time.time()
        job.pid = None
        self._save(job)

    def _save(self, job: J) -> None:
        """Under the lock: the job's record written, and `on_change` told (every change passes here)."""
        try:
            atomic_write_bytes(job.folder / RECORD_FILE, json.dumps(job.to_record(), indent=1).encode())
        except OSError as e:  # the list in memory is still right; a restart would miss this change
            LOG.warning(one_line(f"{job.folder / RECORD_FILE}: could not write the job's record: {e}"))
        self.on_change()

    def _recover(self) -> int:
        """Load the recorded jobs under `root`; the next id."""
        highest = 0
        try:
            # A symlink among them was not made by a server (`_new_folder`): it is left alone.
            folders = (
                sorted(p for p in self.root.iterdir() if p.is_dir() and not p.is_symlink())
                if self.root.is_dir()
                else []
            )
        except OSError:
            folders = []
        for folder in folders:
            m = _FOLDER.match(folder.name)
            if m is None:
                continue
            highest = max(highest, int(m[1]))
            job = self._read(folder, int(m[1]))
            if job is None or job.id in self._jobs:
                continue
            if job.status in ACTIVE:  # its server died with it
                _kill_orphan(job)
                self._set(job, "failed", server_stopped_line(job.status))
                job.ended_at = None  # when it stopped is not known
                self._save(job)
            self._jobs[job.id] = job
        return max(highest + 1, self._recorded_next_id())

    def _read(self, folder: Path, folder_id: int) -> J | None:
        path = folder / RECORD_FILE
        if not path.is_file():
            return None  # a folder from before job records, or one whose job never got recorded
        try:
            if path.stat().st_size > MAX_RECORD_BYTES:
                raise ValueError(f"larger than {MAX_RECORD_BYTES} bytes")
            job = self.job_type.from_record(json.loads(path.read_text()))
            if job.id != folder_id:
                raise ValueError(f"id {job.id} in the folder of job {folder_id}")
        except (OSError, ValueError, TypeError, KeyError) as e:
            LOG.warning(one_line(f"{path}: not a job record, left out of the list ({type(e).__name__}: {e})"))
            return None
        job.folder = folder  # where it is now
        return job  # type: ignore[return-value]

    def _recorded_next_id(self) -> int:
        try:
            return int((self.root / NEXT_ID_FILE).read_text().strip())
        except (OSError, ValueError):
            return 1


def _nothing() -> None:
    pass


def _kill_orphan(job: Job) -> None:
    """SIGKILL the process group a dead server's running job left, if its leader still runs in the job's
    folder (a pid reused by another process is left alone)."""
    if job.pid is None:
        return
    try:
        if os.getpgid(job.pid) != job.pid or Path(f"/proc/{job.pid}/cwd").resolve() != job.folder.resolve():
            return
        os.killpg(job.pid, signal.SIGKILL)
    except OSError:
        return  # gone, or not ours
