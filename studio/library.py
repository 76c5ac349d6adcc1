"""The library panel: clips, characters, dataset yamls, configs and arg files found in the data folders.

Each data folder is MimicKit-shaped (`motions/`, `assets/`, `datasets/`, `envs/`, `agents/`, `engines/`,
`args/`). Reading a clip or a character costs milliseconds, so results are cached per file and
re-read only when the file's size or mtime changes.

A file that cannot be read (a corrupt or hostile clip, a broken character, a binary arg file) is one
entry with its one-line `error`, never a failed listing: the rest of the panel stays usable.
"""

from __future__ import annotations

import hashlib
import threading
import time
from collections.abc import Callable
from pathlib import Path, PurePosixPath
from typing import Any, TypeVar

import yaml

from mimickit.anim.mjcf_char_model import load_char_model
from mimickit.util.arg_parser import ArgParser
from mimickit.util.config import load_yaml_text, read_text_file
from mimickit.util.errors import MimicKitError
from mimickit.util.warn import collect_warnings
from studio.parsing import read_motion
from studio.scene.clip_pose import default_pose
from studio.security import PathError, confine, display_path
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
        self._hashes = FileCache()  # uploads' SHA-256 (a cache keeps one value per file)
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

    def character_pose(self, path: Path) -> dict[str, Any]:
        """What the scene needs to show a character in its default pose (`path` confined by the
        caller): each body with its parent, world position and orientation (xyzw) in that pose, and
        the joint that moves it (type, DoF columns in a clip frame, axis, limits)."""
        pose = default_pose(path)
        char = pose.char
        bodies = []
        for j, name in enumerate(char.get_body_names()):
            joint = char.get_joint(j)
            bodies.append(
                {
                    "name": name,
                    "parent": char.get_parent_id(j),
                    "pos": [round(float(v), 6) for v in pose.body_pos[0, j]],
                    "rot": [round(float(v), 6) for v in pose.body_rot[0, j]],
                    "joint": {
                        "name": joint.name,
                        "type": joint.type.name.lower(),
                        "dof_idx": joint.dof_idx,  # clip column 6 + dof_idx
                        "dof_dim": joint.dof_dim,
                        "axis": None if joint.axis is None else [float(v) for v in joint.axis],
                        "low": [float(v) for v in joint.low],
                        "high": [float(v) for v in joint.high],
                    },
                }
            )
        return {
            "path": self._display(path),
            "name": path.stem,
            "dof_size": char.get_dof_size(),
            "frame_dim": 6 + char.get_dof_size(),
            "frame": [float(v) for v in pose.motion.frames[0]],
            "feet": pose.feet,
            "bodies": bodies,
        }

    # -- motions ----------------------------------------------------------------------------------

    def motions(self) -> list[dict[str, Any]]:
        """Every clip: its header facts and the character guessed for it."""
        return self._listing("motions", self._scan_motions)

    def motions_listed(self) -> list[dict[str, Any]] | None:
        """`motions()` when a listing is memoised (a stale one is re-scanned in the background), else
        None: for a caller on the event loop, which must not scan."""
        with self._lists_lock:
            listed = "motions" in self._lists
        return self.motions() if listed else None

    def motion_info(self, path: Path) -> dict[str, Any]:
        """One clip's header facts (cached), or its `error`."""
        return self._cache.get(path, _motion_info)

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
                if info["character"] is None:
                    info["characters_tried"] = characters_tried(info["frame_dim"], chars)
                    info["character_error"] = no_character_line(info["frame_dim"], info["characters_tried"])
            out.append({"path": shown, "name": f.stem, "upload": f.is_relative_to(uploads), **info})
        return out

    # -- datasets and configs ---------------------------------------------------------------------

    def datasets(self) -> list[dict[str, Any]]:
        """Dataset yamls with their clips: each entry's file, weight, share of the total weight, where
        it resolves and whether it is there (a dataset of MimicKit clips needs `--data-dir`)."""
        files = self._files("datasets", "*.yaml")
        return [
            self._with_clips({"path": shown, "name": f.stem, **self._cache.get(f, _dataset_info)}) for shown, f in files
        ]

    def _with_clips(self, info: dict[str, Any]) -> dict[str, Any]:
        motions = info.get("motions")
        if not motions:
            return info
        total = sum(m["weight"] for m in motions)
        clips = [{**m, "share": m["weight"] / total if total else 0.0, **self.resolve(m["file"])} for m in motions]
        return {**info, "motions": clips, "missing": sum(not c["exists"] for c in clips)}

    def resolve(self, path: str) -> dict[str, Any]:
        """Where a file a config names (`data/motions/x.pkl`, absolute) lies: `resolved` (None when
        outside the studio's folders) and `exists`."""
        try:
            found = confine(path, self.settings.readable_roots, must_exist=False)
        except PathError:
            return {"resolved": None, "exists": False}
        return {"resolved": self._display(found), "exists": found.is_file()}

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

    # -- uploads ------------------------------------------------------------------------------------

    def upload_of(self, data: bytes) -> Path | None:
        """The upload that holds exactly these bytes (same size, same SHA-256), if there is one."""
        folder = self.settings.uploads_dir
        digest = hashlib.sha256(data).hexdigest()
        for f in sorted(folder.glob("*.pkl")) if folder.is_dir() else []:
            same_size = f.is_file() and not f.is_symlink() and f.stat().st_size == len(data)
            if same_size and self._hashes.get(f, _sha256) == digest:
                return f
        return None

    def delete_upload(self, path: str) -> Path:
        """Remove one uploaded clip; PathError for anything but a `.pkl` directly in the uploads folder
        (a data folder's clip, a path out of it, a symlink leading out: 403; a missing one: 404)."""
        folder = self.settings.uploads_dir.resolve()
        name = PurePosixPath(path.replace("\\", "/"))
        # A bare name is one in the uploads folder; an absolute path must resolve into it.
        if not name.is_absolute() and len(name.parts) != 1:
            raise PathError(f"only an uploaded clip can be deleted (a name or a path in uploads/): {path}", 403)
        given = Path(name) if name.is_absolute() else folder / name
        target = confine(str(given), [folder])
        if given.is_symlink() or target.parent != folder or target.suffix != ".pkl" or not target.is_file():
            raise PathError(f"only an uploaded .pkl clip can be deleted: {path}", 403)
        target.unlink()
        self.invalidate()
        return target

    # -- one config or arg file, read-only ---------------------------------------------------------

    def config_dirs(self) -> list[Path]:
        """The folders whose files open read-only: arg files, env/agent/engine yamls, datasets."""
        kinds = (*CONFIG_KINDS, "datasets")
        return [
            d.resolve() for d in [*self.settings.arg_dirs, *(r / k for r in self.settings.data_dirs for k in kinds)]
        ]

    def config_file(self, path: Path) -> dict[str, Any]:
        """The text of one arg file or yaml (`path` resolved and confined by the caller) and what it
        trains: the env config, the clip or dataset and the character it names, resolved.
        PathError when the file is not in a config folder (403) or too large (413)."""
        folder = next((d for d in self.config_dirs() if path.is_relative_to(d)), None)
        if folder is None or path.suffix not in (".txt", ".yaml", ".yml"):
            raise PathError(f"{path.name}: not an arg file or a config in the studio's folders", 403)
        size = path.stat().st_size
        if size > MAX_CONFIG_BYTES:
            raise PathError(f"{path.name}: {size} bytes, a config shown here may have {MAX_CONFIG_BYTES}", 413)
        text = read_text_file(path, "config")
        kind = "arg_file" if path.suffix == ".txt" else folder.name
        out: dict[str, Any] = {"path": self._display(path), "name": path.stem, "kind": kind, "text": text}
        if kind == "arg_file":
            info = self._cache.get(path, _arg_file_info)
            out.update(info)
            if "args" in info:
                out["trains"] = self._arg_file_trains(info["args"])
        elif kind == "envs":
            out["trains"] = self._env_trains(path)
        elif kind == "datasets":
            out.update(self._with_clips(self._cache.get(path, _dataset_info)))
        return out

    def _arg_file_trains(self, args: dict[str, list[str]]) -> dict[str, Any]:
        """The env config an arg file names and what it trains (the arg file's own `--motion_file`
        and `--char_file` win over the env config's, as in `mimickit train`)."""
        env = (args.get("env_config") or [None])[0]
        trains: dict[str, Any] = {"env_config": self._named(env) if env else None}
        if env and trains["env_config"]["exists"]:
            trains.update(self._env_trains(confine(env, self.settings.readable_roots)))
        for key in ("motion_file", "char_file"):
            if args.get(key):
                trains[key] = {**self._named(args[key][0]), "from": "arg file"}
        if trains.get("motion_file"):
            trains["motion_file"]["kind"] = _motion_kind(trains["motion_file"]["file"])
        return trains

    def _env_trains(self, path: Path) -> dict[str, Any]:
        fields = self._cache.get(path, _env_fields)
        if "error" in fields:
            return {"error": fields["error"]}
        out: dict[str, Any] = {}
        for key in ("motion_file", "char_file"):
            if fields.get(key):
                out[key] = {**self._named(fields[key]), "from": "env config"}
        if "motion_file" in out:
            out["motion_file"]["kind"] = _motion_kind(out["motion_file"]["file"])
        return out

    def _named(self, file: str) -> dict[str, Any]:
        return {"file": file, **self.resolve(file)}


MAX_CONFIG_BYTES = 1024 * 1024


def _motion_kind(file: str) -> str:
    return "dataset" if file.endswith((".yaml", ".yml")) else "clip"


def _env_fields(path: Path) -> dict[str, Any]:
    """`motion_file` and `char_file` of an env yaml (top level or under `env:`), as written."""
    try:
        data = load_yaml_text(read_text_file(path, "env config"), path) or {}
    except MimicKitError as e:
        return {"error": one_line(str(e))}
    if not isinstance(data, dict):
        return {"error": f"{path.name}: not an env config (no mapping at the top)"}
    env = data.get("env") if isinstance(data.get("env"), dict) else {}
    return {k: str(v) for k in ("motion_file", "char_file") if (v := env.get(k, data.get(k)))}


def characters_tried(frame_dim: int, chars: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Why each character does not take a clip of `frame_dim` values per frame."""
    out = []
    for c in chars:
        if "error" in c:
            reason = f"did not load: {c['error']}"
        else:
            reason = f"{c['dof_size']} DoFs: takes {c['frame_dim']} values per frame"
        out.append({"path": c["path"], "reason": reason})
    return out


def no_character_line(frame_dim: int, tried: list[dict[str, Any]]) -> str:
    """One line: the clip's width and, per character tried, why it does not fit."""
    head = f"no character fits {frame_dim} values per frame (6 root + {frame_dim - 6} DoFs)"
    if not tried:
        return head + "; no character found under assets/"
    return head + "; tried " + "; ".join(f"{Path(t['path']).name} ({t['reason']})" for t in tried)


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _character_info(path: Path) -> dict[str, Any]:
    try:
        with collect_warnings():  # dropped, as before: the panel scans every character
            char = load_char_model(path)
    except MimicKitError as e:
        return {"name": path.stem, "error": one_line(str(e))}
    d = char.get_dof_size()
    return {"name": path.stem, "num_bodies": len(char.get_body_names()), "dof_size": d, "frame_dim": 6 + d}


def _motion_info(path: Path) -> dict[str, Any]:
    try:
        with collect_warnings():  # NaN columns are reported, not warned
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
