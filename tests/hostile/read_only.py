"""A folder nobody can write into, for root too: `chmod 500` for a normal user; as root (which ignores
permissions, e.g. in CI containers) the immutable attribute (`chattr +i`)."""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest


@contextlib.contextmanager
def read_only_dir(path: Path) -> Iterator[Path]:
    path.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0:
        path.chmod(0o500)
        try:
            yield path
        finally:
            path.chmod(0o700)
        return
    if shutil.which("chattr") is None or subprocess.run(["chattr", "+i", str(path)], capture_output=True).returncode:
        pytest.skip("running as root without chattr +i: no way to make a read-only folder")
    try:
        yield path
    finally:
        subprocess.run(["chattr", "-i", str(path)], check=True)
