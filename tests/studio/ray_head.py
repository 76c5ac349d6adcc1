"""A Ray head on this machine for the Ray executor's tests and benchmark: `ray start --head --block` with
its own temp dir, free ports and N CPUs, in its own process group, stopped (and every process that names
its session folder killed) on exit."""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

START_TIMEOUT_S = 120.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _pids_mentioning(text: str) -> list[int]:
    pids = []
    for proc in Path("/proc").iterdir():
        if proc.name.isdigit():
            with contextlib.suppress(OSError):
                if text.encode() in (proc / "cmdline").read_bytes():
                    pids.append(int(proc.name))
    return pids


@contextlib.contextmanager
def local_ray_head(num_cpus: int) -> Iterator[str]:
    """The head's dashboard URL (its Job Submission API) while it runs."""
    from ray.job_submission import JobSubmissionClient

    temp_dir = tempfile.mkdtemp(prefix="rayt", dir="/tmp")  # short: Ray's socket paths have a length limit
    dashboard = free_port()
    argv = [str(Path(sys.executable).with_name("ray")), "start", "--head", "--block", "--disable-usage-stats"]
    argv += ["--port", str(free_port()), "--dashboard-port", str(dashboard), "--num-cpus", str(num_cpus)]
    argv += ["--temp-dir", temp_dir, "--include-dashboard", "true", "--object-store-memory", str(80 * 2**20)]
    log_path = Path(temp_dir) / "head.log"
    with open(log_path, "w") as log:
        head = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    url = f"http://127.0.0.1:{dashboard}"
    try:
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            if head.poll() is not None:
                raise RuntimeError(f"ray start exited: {log_path.read_text()[-2000:]}")
            try:
                JobSubmissionClient(url)
                break
            except Exception:
                if time.monotonic() > deadline:
                    raise RuntimeError(f"the Ray head did not answer in {START_TIMEOUT_S} s") from None
                time.sleep(0.5)
        yield url
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(head.pid, signal.SIGTERM)
        with contextlib.suppress(subprocess.TimeoutExpired):
            head.wait(10)
        with contextlib.suppress(ProcessLookupError):
            os.killpg(head.pid, signal.SIGKILL)  # `ray start --block` does not always end on SIGTERM
        head.wait()
        for pid in _pids_mentioning(temp_dir):  # workers outside the group still name the session folder
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        shutil.rmtree(temp_dir, ignore_errors=True)
