"""What the studio's background jobs (evals, videos) share about their `mimickit` child process: how
it is killed and how its failure is told in one line."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
from pathlib import Path

from studio.library import one_line


def kill_group(proc: subprocess.Popen[bytes]) -> None:
    """SIGKILL the job's process group (it leads its own session), if it still runs."""
    if proc.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)


def failure_line(command: str, console: Path, code: int) -> str:
    """`mimickit`'s last `error: ...` line, else the last line printed, else the exit code."""
    try:
        lines = [line.strip() for line in console.read_text(errors="replace").splitlines() if line.strip()]
    except OSError:
        lines = []
    errors = [line for line in lines if line.startswith("error:")]
    last = errors[-1] if errors else lines[-1] if lines else None
    how = f"killed by signal {-code}" if code < 0 else f"exit code {code}"
    return one_line(f"{command} failed ({how}): {last}" if last else f"{command} failed ({how})")
