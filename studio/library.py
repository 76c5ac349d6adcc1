"""The library panel: clips, characters, dataset yamls, configs and arg files found in the data folders.

Each data folder is MimicKit-shaped (`motions/`, `assets/`, `datasets/`, `envs/`, `agents/`, `engines/`,
`args/`). Reading a clip or a character costs milliseconds, so results are cached per file and
re-read only when the file's size or mtime changes.

A file that cannot be read (a corrupt or hostile clip, a broken character, a binary arg file) is one
entry with its one-line `error`, never a failed listing: the rest of the panel stays usable.
"""

from __future__ import annotations

import threading
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import yaml

from mimickit.anim.mjcf_char_model import load_char_model
from mimickit.util.arg_parser import ArgParser
from mimickit.util.config import load_yaml_text, read_text_file
from mimickit.util.errors import MimicKitError
from studio.parsing import read_motion
from studio.security import display_path
from studio.settings import Settings

T = TypeVar("T")
CONFIG_KINDS = ("envs", "agents", "engines")


class FileCache:
    """Memoises `fn(path)` per (path, size, mtime); thread-safe."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._items: dict[Path, tuple[tuple[int, int], Any]] = {}

    def get(self, path: Path, fn: Callable[[Path], T]) -> T:
        """`fn(path)`, cached; a file that vanished or cannot be read (or an unexpected failure
        inside `fn`) gives `{"error": "..."}` with one line instead of raising."""
        try:
            st = path.stat()
        except OSError as e:
            return {"error": f"{path.name}: cannot read it ({e.strerror or e})"}  # type: ignore[return-value]
        key = (st.st_size, st.st_mtime_ns)
        with self._lock:
            hit = self._items.get(path)
        if hit and hit[0] == key:
            return hit[1]
        try:
            value = fn(path)
        except Exception as e:  # noqa: BLE001 - one bad file is one entry's error, not a failed listing
            value = {"error": entry_error(path, e)}  # type: ignore[assignment]
        with self._lock:
            self._items[path] = (key, value)
        return value


LIST_TTL_S = 2.0  # a listing older than this is re-scanned (in the background) when next asked for


class Library:
    """Scans the data folders (the user's first, then the project's) and the uploads folder."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self._cache = FileCache()
        self._lists: dict[str, tuple[float, Any]] = {}
        self._lists_lock = threading.Lock()
        self._refreshing: set[str] = set()

    def _listing(self, key: str, scan: Callable[[], T]) -> T:
        """`scan()`, memoised: a stale listing is returned at once and re-scanned in the background,
        so dashboards polling the library never wait for a scan (300 clips: ~15 ms of stat calls)."""
        with self._lists_lock:
            hit = self._lists.get(key)
            stale = hit is not None and time.monotonic() - hit[0] >= LIST_TTL_S
            if stale and key not in self._refreshing:
                self._refreshing.add(key)
                threading.Thread(target=self._refresh, args=(key, scan), daemon=True).start()
        if hit is not None:
            return hit[1]
        return self._refresh(key, scan)

    def _refresh(self, key: str, scan: Callable[[], T]) -> T:
        try:
            value = scan()
            with self._lists_lock:
                self._lists[key] = (time.monotonic(), value)
            return value
        finally:
            with self._lists_lock:
                self._refreshing.discard(key)

    def invalidate(self) -> None:
        """Forget the listings (after an upload, so the new clip shows at once)."""
        with self._lists_lock:
            self._lists.clear()

    # -- files ------------------------------------------------------------------------------------

    def _files(self, sub: str, pattern: str) -> list[tuple[str, Path]]:
        """(display path, file) pairs; a user's file shadows the project's at the same `data/` path."""
        seen: dict[str, Path] = {}
        for root in self.settings.data_dirs:
            for f in sorted((root / sub).glob(pattern)) if (root / sub).is_dir() else []:
                if f.is_file():
                    seen.setdefault(display_path(f, self.settings.data_dirs), f)
        return list(seen.items())

    def _display(self, p: Path) -> str:
        return display_path(p, self.settings.data_dirs)

    # -- characters -------------------------------------------------------------------------------

    def characters(self) -> list[dict[str, Any]]:
        """Every MJCF under `assets/` that loads as a character with at least one DoF."""
        return self._listing("characters", self._scan_characters)

    def _scan_characters(self) -> list[dict[str, Any]]:
        out = []
        for shown, f in self._files("assets", "**/*.xml"):
            info = self._cache.get(f, _character_info)
            if info.get("dof_size", 0) > 0 or "error" in info:  # props (no DoFs) are not characters
                out.append({"path": shown, "name": f.stem, **info})
        return out

    def character_for_width(self, frame_dim: int, clip: Path, chars: list[dict[str, Any]] | None = None) -> str | None:
        """Guess a clip's character: the DoF count must fit; a folder name matching the clip's wins."""
        best, best_score = None, -1
        for c in chars if chars is not None else self.characters():
            if c.get("frame_dim") != frame_dim:
                continue
            folder, stem = Path(c["path"]).parent.name, Path(c["path"]).stem
            score = 2 * (folder == clip.parent.name) + clip.stem.startswith(folder) + (stem == folder)
            if score > best_score:
                best, best_score = c["path"], score
        return best

    # -- motions ----------------------------------------------------------------------------------

    def motions(self) -> list[dict[str, Any]]:
        """Every clip: its header facts and the character guessed for it."""
        return self._listing("motions", self._scan_motions)

    def _scan_motions(self) -> list[dict[str, Any]]:
        files = self._files("motions", "**/*.pkl")
        uploads = self.settings.uploads_dir
        if uploads.is_dir():
            files += [(str(f), f) for f in sorted(uploads.glob("*.pkl"))]
        out, chars = [], self.characters()
        for shown, f in files:
            info = dict(self._cache.get(f, _motion_info))
            if "frame_dim" in info:
                info["character"] = self.character_for_width(info["frame_dim"], f, chars)
            out.append({"path": shown, "name": f.stem, "upload": f.is_relative_to(uploads), **info})
        return out

    # -- datasets and configs ---------------------------------------------------------------------

    def datasets(self) -> list[dict[str, Any]]:
        files = self._files("datasets", "*.yaml")
        return [{"path": shown, "name": f.stem, **self._cache.get(f, _dataset_info)} for shown, f in files]

    def configs(self) -> dict[str, list[dict[str, Any]]]:
        return self._listing("configs", self._scan_configs)

    def _scan_configs(self) -> dict[str, list[dict[str, Any]]]:
        out: dict[str, list[dict[str, Any]]] = {k: [] for k in CONFIG_KINDS}
        for kind in CONFIG_KINDS:
            out[kind] = [{"path": shown, "name": f.stem} for shown, f in self._files(kind, "*.yaml")]
        out["arg_files"] = self.arg_files()
        out["datasets"] = self.datasets()
        return out

    def arg_files(self) -> list[dict[str, Any]]:
        """MimicKit arg files (`--key value` lines) from `args/` folders, with their keys."""
        out, seen = [], set()
        for d in self.settings.arg_dirs:
            for f in sorted(d.glob("*.txt")) if d.is_dir() else []:
                if f.name in seen:
                    continue
                seen.add(f.name)
                info = self._cache.get(f, _arg_file_info)  # {"args": ...} or {"error": ...}
                out.append({"path": str(f), "name": f.stem, "args": {}, **info})
        return out


def _character_info(path: Path) -> dict[str, Any]:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            char = load_char_model(path)
    except MimicKitError as e:
        return {"name": path.stem, "error": one_line(str(e))}
    d = char.get_dof_size()
    return {"name": path.stem, "num_bodies": len(char.get_body_names()), "dof_size": d, "frame_dim": 6 + d}


def _motion_info(path: Path) -> dict[str, Any]:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # NaN columns are reported, not warned
            m = read_motion(path, sanitize_nan=False, in_child=False)  # hundreds of files: see read_motion
    except MimicKitError as e:
        return {"error": one_line(str(e))}
    return {
        "fps": m.fps,
        "loop_mode": m.loop_mode.name.lower(),
        "num_frames": m.num_frames,
        "duration": round(m.duration, 6),
        "frame_dim": m.frame_dim,
        "nan_columns": list(m.nan_columns),
    }


def _dataset_info(path: Path) -> dict[str, Any]:
    try:
        data = load_yaml_text(read_text_file(path, "dataset yaml"), path) or {}
        motions = [{"file": str(m.get("file")), "weight": float(m.get("weight", 1.0))} for m in data.get("motions", [])]
    except MimicKitError as e:
        return {"name": path.stem, "error": one_line(str(e))}
    except (yaml.YAMLError, AttributeError, TypeError, ValueError) as e:
        return {"name": path.stem, "error": one_line(f"{path.name}: not a dataset yaml ({e})")}
    return {"name": path.stem, "motions": motions}


def _arg_file_info(path: Path) -> dict[str, Any]:
    """`args`: the `--key values...` table of an arg file, for the launch form; or its `error`."""
    parser = ArgParser()
    try:
        parser.load_file(str(path))
    except MimicKitError as e:
        return {"error": one_line(str(e))}
    return {"args": {k: parser.parse_strings(k) for k in parser.all_keys()}}


MAX_ERROR_CHARS = 300


def one_line(text: str) -> str:
    """An error as the page shows it: its first line, at most `MAX_ERROR_CHARS` characters."""
    first = (text.strip().splitlines() or [""])[0]
    return first if len(first) <= MAX_ERROR_CHARS else first[: MAX_ERROR_CHARS - 1] + "…"


def entry_error(path: Path, e: BaseException) -> str:
    """One line for a file that could not be read: the MimicKitError's own line, else the file,
    the exception's type and its first line."""
    if isinstance(e, MimicKitError):
        return one_line(str(e))
    return one_line(f"{path.name}: cannot read it ({type(e).__name__}: {one_line(str(e))})")
