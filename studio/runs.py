"""The run manager: training runs as subprocesses, at most N at once, the rest queued.

Every run is its own OS process (`mimickit train ...`) in its own process group, working in and
writing to its run folder (`mimickit.run_folder`: args.json, configs, metrics.jsonl, model.pt,
state.json; the manager adds console.log with its stdout/stderr). When a trainer exits, the run's end
state (finished / stopped / diverged / failed, with the line that says why) is the one its state.json
records; the exit code only speaks when the trainer recorded nothing. One manager thread starts and
reaps all processes. On Linux each child asks the kernel to send it
SIGTERM when that thread dies, so a killed server never leaves a trainer running that nobody watches:
the trainer saves its checkpoint, and the next server marks the run `interrupted`, ready to resume.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import functools
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

from mimickit.run_folder import MODEL_FILE, EndState, RunFolder
from mimickit.util.paths import IMPORT_ROOT
from studio.registry import ACTIVE, Registry, Run, RunStatus
from studio.run_summary import run_summary, seed_of
from studio.settings import Settings

CHECKPOINT = MODEL_FILE
POLL_S = 0.2


class RunError(Exception):
    """A run request that cannot be done now (HTTP 409) or names nothing (404)."""

    def __init__(self, message: str, status: int = 409) -> None:
        super().__init__(message)
        self.status = status


def train_command(
    trainer: list[str],
    arg_file: str | Path,
    out_dir: str | Path,
    *,
    num_envs: int | None = None,
    max_samples: int | None = None,
    motion_file: str | None = None,
    rand_seed: int | None = None,
    data_dir: str | Path | None = None,
    model_file: str | Path | None = None,
) -> list[str]:
    """The argv of one training process: `trainer` (`mimickit train`) plus MimicKit's arguments."""
    argv = [*trainer, "--arg_file", str(arg_file), "--out_dir", str(out_dir)]
    optional = {
        "num_envs": num_envs,
        "max_samples": max_samples,
        "motion_file": motion_file,
        "rand_seed": rand_seed,
        "data_dir": data_dir,
        "model_file": model_file,
    }
    for key, value in optional.items():
        if value is not None:
            argv += [f"--{key}", str(value)]
    return argv


class RunManager:
    def __init__(self, settings: Settings, registry: Registry) -> None:
        self.settings = settings
        self.registry = registry
        self._procs: dict[int, subprocess.Popen[bytes]] = {}
        self._adopted: dict[int, int] = {}  # run id -> pid of a process a previous server started
        self._kill_at: dict[int, float] = {}  # run id -> time to SIGKILL a run that ignores SIGTERM
        self._lock = threading.RLock()
        self._wake = threading.Event()
        self._closed = threading.Event()
        self._recover()
        self._thread = threading.Thread(target=self._loop, name="run-manager", daemon=True)
        self._thread.start()

    # -- requests (any thread) ----------------------------------------------------------------------

    def submit(self, name: str, config: dict[str, Any]) -> Run:
        """Queue a new run; it starts as soon as a slot is free."""
        run = self.registry.create(name, config, lambda i: str(self.settings.runs_dir / f"{i:04d}-{_slug(name)}"))
        self._wake.set()
        return run

    def stop(self, run_id: int) -> Run:
        """Queued: never starts. Running: SIGTERM (the trainer checkpoints and exits), SIGKILL if slow."""
        with self._lock:
            run = self.get(run_id)
            if run.status == RunStatus.QUEUED:
                return self.registry.update(run_id, status=RunStatus.STOPPED, ended_at=time.time())
            if run.status not in ACTIVE:
                raise RunError(f"run {run_id} is {run.status.value}, not running")
            if run.status == RunStatus.RUNNING:
                run = self.registry.update(run_id, status=RunStatus.STOPPING)
                self._signal(run, signal.SIGTERM)
                self._kill_at[run_id] = time.monotonic() + self.settings.stop_timeout_s
            return run

    def resume(self, run_id: int, max_samples: int | None = None) -> Run:
        """Queue an ended run again: a new process in the same folder, from its checkpoint, with the
        budget `max_samples` (total samples, more than it has trained) or the one it had."""
        with self._lock:
            run = self.get(run_id)
            if not run.status.finished:
                raise RunError(f"run {run_id} is {run.status.value}; only a run that ended can be resumed")
            checkpoint = RunFolder(run.out_dir).model_file
            if not checkpoint.is_file():
                raise RunError(f"run {run_id} has no checkpoint ({CHECKPOINT}) to resume from")
            config = {**run.config, "model_file": str(checkpoint)}
            done = run_summary(run.out_dir)["samples"] or 0
            if max_samples is not None:
                if max_samples <= done:
                    raise RunError(
                        f"max_samples {max_samples} is not more than the {done} samples run {run_id} has trained"
                    )
                config["max_samples"] = max_samples
            elif run.status == RunStatus.FINISHED:
                raise RunError(
                    f"run {run_id} reached its budget ({done} samples); give a larger max_samples to continue it"
                )
            run = self.registry.update(
                run_id, status=RunStatus.QUEUED, config=config, pid=None, exit_code=None, ended_at=None, reason=None
            )
        self._wake.set()
        return run

    def again(self, run_id: int) -> Run:
        """A new run with the same arg file and overrides as run `run_id`, and the seed it used."""
        run = self.get(run_id)
        seed = seed_of(run.out_dir)
        if seed is None:
            raise RunError(f"run {run_id} recorded no seed (its trainer wrote no args.json yet)")
        config = {k: v for k, v in run.config.items() if k != "model_file"}
        return self.submit(f"{run.name} seed {seed}", {**config, "rand_seed": seed})

    def delete(self, run_id: int) -> None:
        """Remove the row and the run's folder (only ever a folder inside the runs folder)."""
        with self._lock:
            run = self.get(run_id)
            if run.status in ACTIVE:
                raise RunError(f"run {run_id} is {run.status.value}; stop it before deleting it")
            self.registry.delete(run_id)
        out_dir = Path(run.out_dir).resolve() if run.out_dir else None
        runs_dir = self.settings.runs_dir.resolve()
        if out_dir and out_dir != runs_dir and out_dir.is_relative_to(runs_dir) and out_dir.is_dir():
            shutil.rmtree(out_dir, ignore_errors=True)

    def close(self) -> None:
        self._closed.set()
        self._wake.set()
        self._thread.join(timeout=5)

    # -- the manager thread ---------------------------------------------------------------------------

    def _loop(self) -> None:
        while not self._closed.is_set():
            try:
                with self._lock:
                    self._reap()
                    self._fill_slots()
            except Exception as e:  # keep managing the other runs; the error goes to the server log
                print(f"run manager: {e!r}", file=sys.stderr)
            self._wake.wait(POLL_S)
            self._wake.clear()

    def _reap(self) -> None:
        for run_id, proc in list(self._procs.items()):
            code = proc.poll()
            if code is not None:
                del self._procs[run_id]
                self._finish(run_id, code)
        for run_id, pid in list(self._adopted.items()):
            if not _pid_alive(pid):
                del self._adopted[run_id]
                self._finish(run_id, None)
        now = time.monotonic()
        for run_id, deadline in list(self._kill_at.items()):
            if now > deadline:
                del self._kill_at[run_id]
                run = self.registry.find(run_id)
                if run and run.status == RunStatus.STOPPING:
                    self._signal(run, signal.SIGKILL)

    def _finish(self, run_id: int, code: int | None) -> None:
        """Status from the run folder's state.json; `code` None: a process we did not start."""
        self._kill_at.pop(run_id, None)
        run = self.registry.find(run_id)
        if run is None:
            return
        status, reason = end_status(run, code)
        self.registry.update(run_id, status=status, reason=reason, exit_code=code, ended_at=time.time(), pid=None)

    def _fill_slots(self) -> None:
        active = len(self._procs) + len(self._adopted)
        for run in self.registry.list(RunStatus.QUEUED):
            if active >= self.settings.max_concurrent_runs:
                return
            self._start(run)
            active += 1

    def _start(self, run: Run) -> None:
        cfg = run.config
        if not run.out_dir:  # never run a trainer in the server's working directory
            self.registry.update(run.id, status=RunStatus.FAILED, ended_at=time.time())
            return
        out_dir = Path(run.out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        argv = train_command(
            self.settings.trainer,
            cfg["arg_file"],
            out_dir,
            num_envs=cfg.get("num_envs"),
            max_samples=cfg.get("max_samples"),
            motion_file=cfg.get("motion_file"),
            rand_seed=cfg.get("rand_seed"),
            data_dir=self.settings.data_dir,
            model_file=cfg.get("model_file"),
        )
        # The trainer works in its run folder (MuJoCo's MUJOCO_LOG.TXT and the like land there, not in
        # the server's directory); the project stays importable for `python -m mimickit.cli`.
        path = os.pathsep.join(p for p in (str(IMPORT_ROOT), os.environ.get("PYTHONPATH", "")) if p)
        env = {**os.environ, "PYTHONUNBUFFERED": "1", "PYTHONPATH": path}
        spawned = time.time()  # before the trainer can write its state.json: what it writes is newer
        with open(RunFolder(out_dir).console_file, "ab") as console:
            console.write(f"$ {' '.join(argv)}\n".encode())
            console.flush()
            try:
                proc = subprocess.Popen(
                    argv,
                    stdin=subprocess.DEVNULL,
                    stdout=console,
                    stderr=subprocess.STDOUT,
                    cwd=out_dir,
                    env=env,
                    start_new_session=True,  # its own process group: a stop reaches its children too
                    preexec_fn=functools.partial(_die_with_parent, os.getpid()) if _PRCTL else None,
                )
            except OSError as e:
                console.write(f"could not start: {e}\n".encode())
                self.registry.update(run.id, status=RunStatus.FAILED, ended_at=time.time(), command=argv)
                return
        self._procs[run.id] = proc
        self.registry.update(
            run.id,
            status=RunStatus.RUNNING,
            pid=proc.pid,
            started_at=spawned,
            command=argv,
            attempts=run.attempts + 1,
        )

    # -- start-up ----------------------------------------------------------------------------------

    def _recover(self) -> None:
        """Runs a previous server left running: adopt the live ones, mark the gone ones interrupted."""
        for run in self.registry.list():
            if run.status not in ACTIVE:
                continue
            if run.pid and _pid_alive(run.pid) and run.out_dir in _cmdline(run.pid):
                self._adopted[run.id] = run.pid
            elif run.status == RunStatus.STOPPING:
                self.registry.update(run.id, status=RunStatus.STOPPED, ended_at=time.time(), pid=None)
            else:
                self.registry.update(run.id, status=RunStatus.INTERRUPTED, ended_at=time.time(), pid=None)

    # -- helpers -----------------------------------------------------------------------------------------

    def get(self, run_id: int) -> Run:
        """The run, or RunError 404."""
        run = self.registry.find(run_id)
        if run is None:
            raise RunError(f"no run {run_id}", 404)
        return run

    def _signal(self, run: Run, sig: signal.Signals) -> None:
        if run.pid:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(run.pid, sig)  # pgid == pid: the child leads its own session


def end_status(run: Run, code: int | None) -> tuple[RunStatus, str | None]:
    """How a run's latest process ended: its state.json (when written by that process), else a stop
    the studio asked for, else the exit code (with the trainer's `error: ...` line as the reason)."""
    folder = RunFolder(run.out_dir)
    state = folder.read_state()
    if state is not None and state.state != EndState.RUNNING and state.updated_at >= (run.started_at or 0.0):
        return RunStatus(state.state.value), state.reason or None
    if run.status == RunStatus.STOPPING:
        return RunStatus.STOPPED, None
    if code is None:
        return RunStatus.INTERRUPTED, "its trainer ended while no studio watched it, without recording why"
    if code < 0:
        return RunStatus.FAILED, f"the trainer was killed by {_signal_name(-code)}"
    return RunStatus.FAILED, _error_line(folder) or f"the trainer exited with code {code} without recording why"


def _error_line(folder: RunFolder) -> str | None:
    """The latest process's last `error: ...` line in console.log (how `mimickit` reports a mistake);
    each process's output starts with the `$ argv` line the manager writes."""
    try:
        with folder.console_file.open("rb") as f:
            f.seek(max(0, f.seek(0, 2) - 64 * 1024))
            lines = f.read().decode(errors="replace").splitlines()
    except OSError:
        return None
    starts = [i for i, line in enumerate(lines) if line.startswith("$ ")]
    lines = lines[starts[-1] :] if starts else lines
    errors = [line.strip() for line in lines if line.startswith("error: ")]
    return errors[-1][len("error: ") :] if errors else None


def _signal_name(signum: int) -> str:
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "-", name).strip("-.")[:40] or "run"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    # A zombie is gone for our purposes (a child of ours is reaped by poll(), so this is another's).
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(") ", 1)[1][0] != "Z"
    except (OSError, IndexError):
        return True


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


# prctl(PR_SET_PDEATHSIG, SIGTERM), resolved before any fork so the child only makes the call.
_PR_SET_PDEATHSIG = 1
_PRCTL = None
if sys.platform.startswith("linux"):
    _libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
    _PRCTL = _libc.prctl


def _die_with_parent(parent_pid: int) -> None:
    """In the child before exec: SIGTERM me when the manager thread (the server) dies."""
    _PRCTL(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
    if os.getppid() != parent_pid:  # the server died before the call above took effect
        os._exit(1)
