"""Runs as subprocesses of the server (the default executor).

Each job is one OS process in its own process group (a stop reaches its children too), working in
its run folder and writing its stdout/stderr to console.log; its job id is its pid. On Linux each child
asks the kernel to send it SIGTERM when the server's run-manager thread dies, so a killed server never
leaves a trainer running that nobody watches: the trainer saves its checkpoint, and the next server
marks the run `interrupted`, ready to resume. A process a previous server started (the server was
restarted while it ran) is recognised by its pid and its command line, and adopted.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import threading
import time
from pathlib import Path

from studio.child import start_child
from studio.runs.executors.base import Job, JobState, Launch


class LocalExecutor:
    name = "local"
    queues = False  # the run manager keeps the queue (--max-concurrent-runs)

    def __init__(self, stop_timeout_s: float) -> None:
        self.stop_timeout_s = stop_timeout_s
        self._procs: dict[int, subprocess.Popen[bytes]] = {}
        self._started: dict[int, float] = {}
        self._ended: dict[int, Job] = {}
        self._lock = threading.Lock()

    def submit(self, launch: Launch) -> str:
        env = {**os.environ, **launch.env}
        started = time.time()
        with open(launch.console_file, "ab") as console:
            proc = start_child(launch.argv, cwd=launch.work_dir, env=env, stdout=console, stderr=subprocess.STDOUT)
        with self._lock:
            self._procs[proc.pid] = proc
            self._started[proc.pid] = started
        return str(proc.pid)

    def status(self, job_id: str, argv_hint: str = "") -> Job | None:
        pid = int(job_id)
        with self._lock:
            if pid in self._ended:
                return self._ended[pid]
            proc = self._procs.get(pid)
            if proc is not None:
                code = proc.poll()
                if code is None:
                    return Job(JobState.RUNNING, started_at=self._started[pid])
                del self._procs[pid]
                self._ended[pid] = Job(JobState.ENDED, self._started.pop(pid), time.time(), code)
                return self._ended[pid]
        # Not ours: a process a previous server started, if it is still that trainer.
        if _pid_alive(pid) and argv_hint in _cmdline(pid):
            return Job(JobState.RUNNING)
        return None

    def stop(self, job_id: str) -> None:
        pid = int(job_id)
        with contextlib.suppress(ProcessLookupError):
            os.killpg(pid, signal.SIGTERM)  # pgid == pid: the child leads its own session
        timer = threading.Timer(self.stop_timeout_s, self._kill_if_alive, args=(pid,))
        timer.daemon = True
        timer.start()

    def _kill_if_alive(self, pid: int) -> None:
        """SIGKILL a job that outlived its grace period (and is still the same process)."""
        with self._lock:
            proc = self._procs.get(pid)
            alive = proc.poll() is None if proc is not None else (pid not in self._ended and _pid_alive(pid))
        if alive:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(pid, signal.SIGKILL)

    def logs(self, job_id: str) -> str | None:
        return None  # the process writes console.log in its run folder itself

    def close(self) -> None:
        pass


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
