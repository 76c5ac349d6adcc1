"""Where files live: the project's own `data/`, a user's MimicKit data folder, and output folders.

MimicKit configs name files relative to the MimicKit repository root, e.g.
`data/assets/humanoid/humanoid.xml`. A path that starts with `data/` is looked up in the user's data
folder (`--data_dir`) first and then in the project's own `data/`; other relative paths are taken
relative to the working directory, then the data folder.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

PROJECT_ROOT = Path(__file__).resolve().parents[2]
PROJECT_DATA_DIR = PROJECT_ROOT / "data"

_data_dirs: list[Path] = []


def set_data_dir(path: str | Path | None) -> None:
    """Make `path` the first place `data/...` paths are looked up (the project's data stays second)."""
    _data_dirs.clear()
    if path:
        _data_dirs.append(Path(path).expanduser().resolve())


def data_dirs() -> list[Path]:
    dirs = list(_data_dirs)
    if PROJECT_DATA_DIR not in dirs:
        dirs.append(PROJECT_DATA_DIR)
    return dirs


def resolve_data_path(path: str | Path) -> Path:
    """The first existing candidate for `path`; the first candidate if none exists."""
    p = Path(path).expanduser()
    if p.is_absolute():
        return p
    candidates: list[Path] = []
    parts = p.parts
    if parts and parts[0] == "data":
        rest = Path(*parts[1:]) if len(parts) > 1 else Path()
        candidates += [d / rest for d in data_dirs()]
        candidates.append(Path.cwd() / p)
    else:
        candidates.append(Path.cwd() / p)
        candidates += [d / p for d in data_dirs()]
        candidates.append(PROJECT_ROOT / p)
    for c in candidates:
        if c.exists():
            return c
    return candidates[0]


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write a file so that a reader sees either the old or the new content, never half of it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
