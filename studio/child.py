"""How the server starts a child (a trainer, an eval, a video render): in its own session (process
group), so a stop reaches everything it starts, and, on Linux, dying with the server: the kernel sends
it SIGTERM when the server thread that started it dies, `kill -9` of the server included."""

from __future__ import annotations

import errno
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import IO

LAUNCHER = Path(__file__).with_name("die_with_parent.py")


def start_child(
    argv: list[str], *, cwd: Path, env: dict[str, str], stdout: IO[bytes] | int, stderr: IO[bytes] | int
) -> subprocess.Popen[bytes]:
    """Popen `argv` as a new session that dies with this process. FileNotFoundError, as Popen's own,
    when `argv[0]` is no program on PATH."""
    if not _runnable(argv[0], cwd, env):
        raise FileNotFoundError(errno.ENOENT, os.strerror(errno.ENOENT), argv[0])
    launch = argv
    if sys.platform.startswith("linux"):
        launch = [sys.executable, "-I", str(LAUNCHER), str(os.getpid()), "--", *argv]
    return subprocess.Popen(
        launch,
        stdin=subprocess.DEVNULL,
        stdout=stdout,
        stderr=stderr,
        cwd=cwd,
        env=env,
        start_new_session=True,
    )


def _runnable(program: str, cwd: Path, env: dict[str, str]) -> bool:
    """Whether exec finds `program` as Popen would: a path relative to `cwd`, or a name on PATH."""
    if os.sep in program:
        path = cwd / program
        return path.is_file() and os.access(path, os.X_OK)
    return shutil.which(program, path=env.get("PATH", os.defpath)) is not None
