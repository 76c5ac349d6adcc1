"""What a training run records about itself in `args.json` (see `mimickit.learning.run_folder`): the argv as
given, the merged arguments, every effective value, the seed used, the software versions and the
start time. Enough to repeat the run: `--rand_seed <seed>` with the same arguments on the same machine.
"""

from __future__ import annotations

import platform
import subprocess
import time
from importlib import metadata
from pathlib import Path
from typing import Any

import mimickit
from mimickit.learning.run_folder import ARGS_FORMAT
from mimickit.util.paths import PROJECT_ROOT


def args_record(
    argv: list[str],
    table: dict[str, list[str]],
    effective: dict[str, Any],
    seed: int,
    seed_source: str,
    resume: dict[str, Any] | None = None,
    previous: dict[str, Any] | None = None,
    launch: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """args.json's object. `previous` (the folder's args.json before a resume) is kept, with its own
    earlier starts, under `previous_starts`, oldest first. `launch`: how the processes were started
    (`launcher` spawn or torchrun, `world_size`, `local_world_size`, `nodes`; torchrun: `master`, `run_id`)."""
    history: list[dict[str, Any]] = []
    if previous:
        previous = dict(previous)
        history = list(previous.pop("previous_starts", None) or [])
        history.append(previous)
    now = time.time()
    return {
        "format": ARGS_FORMAT,
        "argv": list(argv),
        "args": {k: list(v) for k, v in table.items()},
        "effective": effective,
        "seed": int(seed),
        "seed_source": seed_source,
        "versions": versions(),
        "start_time": now,
        "start_time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(now)),
        "resume": resume,
        "launch": launch,
        "previous_starts": history,
    }


def versions() -> dict[str, str | bool | None]:
    commit, dirty = git_state(PROJECT_ROOT)
    return {
        "mimickit": mimickit.__version__,
        "git_commit": commit,
        "git_dirty": dirty,
        "python": platform.python_version(),
        "torch": _dist_version("torch"),
        "mujoco": _dist_version("mujoco"),
        "numpy": _dist_version("numpy"),
    }


def git_state(root: Path) -> tuple[str | None, bool | None]:
    """(commit, whether tracked files differ from it) of a git checkout at `root`; (None, None) elsewhere."""
    if not (root / ".git").exists():
        return None, None
    try:
        commit = _git(root, "rev-parse", "HEAD")
        dirty = bool(_git(root, "status", "--porcelain", "--untracked-files=no"))
    except (OSError, subprocess.SubprocessError):
        return None, None
    return commit or None, dirty


def _git(root: Path, *args: str) -> str:
    out = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True, timeout=10, check=True)
    return out.stdout.strip()


def _dist_version(name: str) -> str | None:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None
