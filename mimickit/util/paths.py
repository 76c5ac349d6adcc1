"""Where files live: the project's own `data/`, a user's MimicKit data folder, and output folders.

MimicKit configs name files relative to the MimicKit repository root, e.g.
`data/assets/humanoid/humanoid.xml`. A path that starts with `data/` is looked up in the user's data
folder (`--data_dir`) first and then in the project's own `data/`; other relative paths are taken
relative to the working directory, then the data folder, then the project's root (`args/...`).
`DataPaths` is that lookup for one data folder; builders are handed one (the project's data alone,
`PROJECT_DATA`, by default).

The project's files (`data/`, `args/`, `web/`) sit at the top of the source tree, where a checkout and an
editable install read them. A wheel cannot place folders beside site-packages, so `setup.py` copies them
into the package as `mimickit/_share/`; when that folder exists, it is the project's root.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parents[1]
IMPORT_ROOT = PACKAGE_DIR.parent
"""The folder `mimickit` is imported from: the checkout's root, or site-packages when installed."""
_INSTALLED_SHARE = PACKAGE_DIR / "_share"
INSTALLED = _INSTALLED_SHARE.is_dir()
"""Whether this is a normal (non-editable) install, which carries the project's files in the package."""
PROJECT_ROOT = _INSTALLED_SHARE if INSTALLED else IMPORT_ROOT
"""The folder holding the project's `data/`, `args/` and `web/`."""
PROJECT_DATA_DIR = PROJECT_ROOT / "data"
PROJECT_ARGS_DIR = PROJECT_ROOT / "args"
PROJECT_WEB_DIR = PROJECT_ROOT / "web"


def default_output_root() -> Path:
    """Where default output folders (`output/...`) go: the checkout's root, or the working directory
    when installed (site-packages is no place for runs, and may be read-only)."""
    return Path.cwd() if INSTALLED else IMPORT_ROOT


@dataclass(frozen=True)
class DataPaths:
    """Where `data/...` and other relative paths are looked up (the order is the module docstring's).

    Immutable, so one value can be shared by threads; a build takes the one it was given (`--data_dir`
    of a run, the studio's data folder), never a process-wide setting."""

    data_dir: Path | None = None
    """A user's MimicKit data folder (`motions/`, `assets/`, ...), looked up before the project's."""

    def __post_init__(self) -> None:
        if self.data_dir is not None and str(self.data_dir):
            object.__setattr__(self, "data_dir", Path(self.data_dir).expanduser().resolve())
        else:  # "" (an unset `--data_dir`) is no folder, not the working directory
            object.__setattr__(self, "data_dir", None)

    def dirs(self) -> list[Path]:
        """The data folders, first to last: the user's (if any), then the project's."""
        dirs = [self.data_dir] if self.data_dir is not None else []
        return dirs if PROJECT_DATA_DIR in dirs else [*dirs, PROJECT_DATA_DIR]

    def resolve(self, path: str | Path) -> Path:
        """The first existing candidate for `path`; the first candidate if none exists (so that an
        error names where it was looked for first). Absolute paths are returned as they are."""
        p = Path(path).expanduser()
        if p.is_absolute():
            return p
        candidates: list[Path] = []
        parts = p.parts
        if parts and parts[0] == "data":
            rest = Path(*parts[1:]) if len(parts) > 1 else Path()
            candidates += [d / rest for d in self.dirs()]
            candidates.append(Path.cwd() / p)
        else:
            candidates.append(Path.cwd() / p)
            candidates += [d / p for d in self.dirs()]
            candidates.append(PROJECT_ROOT / p)
        for c in candidates:
            if c.exists():
                return c
        return candidates[0]


PROJECT_DATA = DataPaths()
"""The project's own data only: the default of every builder that is given no data folder."""


SYSTEM_DIRS = (Path("/proc"), Path("/sys"), Path("/dev"))  # the kernel's and the devices' folders


def check_output_file(path: str | Path, what: str = "--out") -> Path:
    """`path` if a file may be written there, checked before the work that fills it: not inside a
    system folder (`SYSTEM_DIRS`), not under a file, nothing but a regular file in its place;
    MimicKitError (one line naming `what`) otherwise."""
    from mimickit.util.errors import MimicKitError

    p = Path(path)
    shown = str(p)[:200]
    folder = p.parent.resolve()
    if any(folder == d or folder.is_relative_to(d) for d in SYSTEM_DIRS):
        raise MimicKitError(f"{what} {shown}: not writing into {folder} (a system folder); choose another")
    if folder.exists() and not folder.is_dir():
        raise MimicKitError(f"{what} {shown}: {folder} is not a folder")
    if p.exists() and not p.is_file():
        raise MimicKitError(f"{what} {shown}: exists and is not a regular file")
    return p


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
