"""`start_child`: the program itself runs (same pid, its own session), a missing program is Popen's
FileNotFoundError, and the child dies with the process that started it, even one killed by `kill -9`."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from studio.child import start_child
from tests.studio.conftest import wait_for

pytestmark = pytest.mark.integration
ROOT = Path(__file__).resolve().parents[2]


def test_the_child_is_the_program_in_its_own_session(tmp_path: Path) -> None:
    proc = start_child(
        ["sleep", "30"], cwd=tmp_path, env=dict(os.environ), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        cmdline = wait_for(
            lambda: (Path(f"/proc/{proc.pid}/cmdline").read_bytes() == b"sleep\x0030\x00") or None, 10, "the exec"
        )
        assert cmdline
        assert os.getpgid(proc.pid) == proc.pid and os.getsid(proc.pid) == proc.pid
        assert Path(f"/proc/{proc.pid}/cwd").resolve() == tmp_path.resolve()
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


@pytest.mark.parametrize("program", ["no-such-program-here", "./not-here.sh"])
def test_a_missing_program_is_file_not_found(tmp_path: Path, program: str) -> None:
    with pytest.raises(FileNotFoundError, match=program.lstrip("./")):
        start_child([program], cwd=tmp_path, env=dict(os.environ), stdout=subprocess.DEVNULL, stderr=None)


def test_a_relative_program_is_found_in_its_folder(tmp_path: Path) -> None:
    script = tmp_path / "run.sh"
    script.write_text("#!/bin/sh\necho ran-here\n")
    script.chmod(0o755)
    out = tmp_path / "out.txt"
    with open(out, "wb") as f:
        proc = start_child(["./run.sh"], cwd=tmp_path, env=dict(os.environ), stdout=f, stderr=subprocess.STDOUT)
        assert proc.wait(timeout=30) == 0
    assert out.read_text() == "ran-here\n"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the parent-death signal is Linux's")
def test_the_child_dies_with_a_killed_parent(tmp_path: Path) -> None:
    pid_file = tmp_path / "child.pid"
    parent = subprocess.Popen(
        [
            sys.executable,
            "-c",
            textwrap.dedent(f"""
                import os, subprocess, sys, threading, time
                from pathlib import Path
                sys.path.insert(0, {str(ROOT)!r})
                from studio.child import start_child
                # A parent with busy threads, as the server is.
                for _ in range(4):
                    threading.Thread(target=lambda: [time.sleep(0.001) for _ in iter(int, 1)], daemon=True).start()
                proc = start_child(["sleep", "60"], cwd=Path({str(tmp_path)!r}), env=dict(os.environ),
                                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                Path({str(pid_file)!r}).write_text(str(proc.pid))
                time.sleep(60)
            """),
        ]
    )
    try:
        child = int(wait_for(lambda: pid_file.is_file() and pid_file.read_text(), 30, "the child's pid"))
        wait_for(lambda: Path(f"/proc/{child}/cmdline").read_bytes().startswith(b"sleep"), 10, "the exec")
        parent.kill()
        parent.wait()
        wait_for(lambda: not _alive(child), 10, "the child to die with its parent")
    finally:
        parent.kill()


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(") ", 1)[1][0] != "Z"
    except (OSError, IndexError):
        return False
