"""MimicKit motion clips: the `.pkl` format, read safely and written byte-compatibly.

A clip is a pickled dict `{"loop_mode": int, "fps": number, "frames": [[...], ...]}` with frames
`[root_pos(3), root_rot exp-map(3), dofs(D)]` per row, loop_mode 0 = clamp, 1 = wrap: MimicKit's format,
so its clips load here and clips written here load in MimicKit.

A clip file is untrusted input. It is unpickled by `mimickit.util.safe_pickle` (data only, every
length and index checked) under `ClipLimits`, and its frames are checked row by row, without
expanding them, before numpy converts them: a few kilobytes of shared nested lists cannot become
gigabytes. `load_motion_guarded` / `motion_from_bytes_guarded` do the same in a child process with a
time budget and a memory bound, for a server that must survive any file.
"""

from __future__ import annotations

import contextlib
import itertools
import math
import pickle
import struct
from dataclasses import dataclass
from enum import IntEnum
from pathlib import Path
from typing import Any

import numpy as np

from mimickit.util.errors import MimicKitError
from mimickit.util.guarded import run_guarded
from mimickit.util.limits import ClipLimits, env_var_for
from mimickit.util.paths import atomic_write_bytes
from mimickit.util.safe_pickle import PickleLimitError, UnsafePickleError, safe_loads
from mimickit.util.warn import warn

# The default file-size limit (MIMICKIT_MAX_CLIP_MB raises it for load_motion; converters use this).
MAX_CLIP_BYTES = ClipLimits().max_file_bytes


class LoopMode(IntEnum):
    CLAMP = 0
    WRAP = 1


@dataclass
class Motion:
    """One clip. `frames` is float32 [T, 6 + D]."""

    loop_mode: LoopMode
    fps: float
    frames: np.ndarray
    nan_columns: tuple[int, ...] = ()

    @property
    def num_frames(self) -> int:
        return int(self.frames.shape[0])

    @property
    def frame_dim(self) -> int:
        return int(self.frames.shape[1])

    @property
    def duration(self) -> float:
        return (self.num_frames - 1) / self.fps

    def to_dict(self) -> dict[str, Any]:
        return {
            "loop_mode": int(self.loop_mode),
            "fps": _plain_number(self.fps),
            "frames": self.frames.astype(np.float64).tolist(),
        }


def load_motion(path: str | Path, *, sanitize_nan: bool = True, limits: ClipLimits | None = None) -> Motion:
    """Read and validate a clip. Errors name the file; NaN columns become 0 with a warning.

    `limits` defaults to `ClipLimits.from_env()` (the MIMICKIT_MAX_... variables)."""
    limits = limits or ClipLimits.from_env()
    p = Path(path)
    data = _read_clip_file(p, limits)
    return motion_from_bytes(data, source=str(p), sanitize_nan=sanitize_nan, limits=limits)


def motion_from_bytes(
    data: bytes, *, source: str = "<bytes>", sanitize_nan: bool = True, limits: ClipLimits | None = None
) -> Motion:
    """A clip from the bytes of a `.pkl` file (e.g. an upload); `source` names it in errors."""
    motion = None
    # The error is raised after the handler: inside it, the traceback still holds the half-built clip.
    with contextlib.suppress(MemoryError):
        motion = _parse_clip(data, source, limits or ClipLimits.from_env())
    if motion is None:
        raise MimicKitError(f"{source}: ran out of memory parsing the clip")
    return _sanitized(motion, source, sanitize_nan)


def motion_from_dict(
    obj: Any, *, source: str = "<dict>", sanitize_nan: bool = True, limits: ClipLimits | None = None
) -> Motion:
    """A clip from its unpickled dict, checked against `limits` before anything is converted."""
    return _sanitized(_clip_from_dict(obj, source, limits or ClipLimits.from_env()), source, sanitize_nan)


def load_motion_guarded(path: str | Path, *, sanitize_nan: bool = True, limits: ClipLimits | None = None) -> Motion:
    """`load_motion` in a child process with a time budget and a memory bound.

    For a process that must survive any file (the studio server): the clip is parsed in a
    forkserver child (no fork of a threaded process) limited to `limits.parse_timeout_s` seconds and
    `limits.parse_memory_mb` MB of address space over its start-up size (MIMICKIT_PARSE_TIMEOUT_S,
    MIMICKIT_PARSE_MEMORY_MB). Returns the Motion, or raises one MimicKitError naming the file:
    any error `load_motion` gives, "<path> took longer than 5 s to parse", "<path> needs more than
    2048 MB to parse", or "<path>: the parser process died (SIGSEGV)". Blocks the calling thread
    (run it in a worker thread from async code). A child starts in ~10-30 ms once the fork server
    runs (the first call starts it: ~0.2-0.5 s).
    """
    limits = limits or ClipLimits.from_env()
    p = Path(path)
    _read_clip_file(p, limits, stat_only=True)
    return _guarded(_child_parse_file, (str(p), limits), str(p), limits, sanitize_nan)


def motion_from_bytes_guarded(
    data: bytes, *, source: str = "<bytes>", sanitize_nan: bool = True, limits: ClipLimits | None = None
) -> Motion:
    """`motion_from_bytes` in a child process, with the budgets of `load_motion_guarded`."""
    limits = limits or ClipLimits.from_env()
    _check_size(len(data), source, limits)
    return _guarded(_child_parse_bytes, (bytes(data), source, limits), source, limits, sanitize_nan)


def save_motion(path: str | Path, motion: Motion) -> None:
    """Write a clip in the reference format: a plain pickled dict of python types (atomic)."""
    atomic_write_bytes(path, pickle.dumps(motion.to_dict()))


# --- reading ------------------------------------------------------------------------------------


def _read_clip_file(p: Path, limits: ClipLimits, *, stat_only: bool = False) -> bytes:
    if not p.is_file():
        raise MimicKitError(f"motion file not found: {p}")
    _check_size(p.stat().st_size, str(p), limits)
    if stat_only:
        return b""
    try:
        return p.read_bytes()
    except OSError as e:
        raise MimicKitError(f"{p}: cannot read the clip ({e.strerror or e})") from None


def _check_size(size: int, source: str, limits: ClipLimits) -> None:
    if size > limits.max_file_bytes:
        raise MimicKitError(
            f"{source}: {size} bytes is over the {limits.max_file_mb:g} MB limit for a clip"
            f" (set {env_var_for('max_file_mb')} to allow more)"
        )


def _parse_clip(data: bytes, source: str, limits: ClipLimits) -> Motion:
    """The unsanitized clip in `data`; MemoryError passes through (the caller knows the bound)."""
    try:
        obj = safe_loads(data, limits)
    except PickleLimitError as e:
        raise MimicKitError(f"{source}: {e}") from None
    except UnsafePickleError as e:
        raise MimicKitError(f"{source}: not a MimicKit clip ({e})") from None
    return _clip_from_dict(obj, source, limits)


def _clip_from_dict(obj: Any, source: str, limits: ClipLimits) -> Motion:
    if not isinstance(obj, dict):
        raise MimicKitError(f"{source}: expected a dict with loop_mode, fps, frames; got {type(obj).__name__}")
    missing = [k for k in ("loop_mode", "fps", "frames") if k not in obj]
    if missing:
        raise MimicKitError(f"{source}: missing key(s) {', '.join(missing)}")
    loop_mode = _as_number(obj["loop_mode"], source, "loop_mode")
    if loop_mode not in (0, 1):
        raise MimicKitError(f"{source}: loop_mode must be 0 (clamp) or 1 (wrap), got {_describe(loop_mode)}")
    fps = _fps(obj["fps"], source, limits)
    frames = _frames_array(obj["frames"], source, limits)
    return Motion(LoopMode(int(loop_mode)), fps, frames, _nan_columns(frames))


def _fps(v: Any, source: str, limits: ClipLimits) -> float:
    number = _as_number(v, source, "fps")
    try:
        fps = float(number)
    except OverflowError:
        raise MimicKitError(f"{source}: fps must be a frame rate, got {_describe(number)}") from None
    if not math.isfinite(fps) or not limits.min_fps <= fps <= limits.max_fps:
        raise MimicKitError(
            f"{source}: fps must be between {limits.min_fps:g} and {limits.max_fps:g} frames a second, got {fps!r}"
        )
    return fps


def _as_number(v: Any, source: str, key: str) -> int | float:
    if isinstance(v, np.ndarray):
        if v.size != 1 or v.dtype.kind not in "biuf":
            raise MimicKitError(f"{source}: {key} must be a real number, got an array of {v.size} {v.dtype}")
        v = v.reshape(()).item()
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise MimicKitError(f"{source}: {key} must be a real number, got {type(v).__name__}")
    return v


def _describe(v: Any) -> str:
    """A bounded text for an untrusted scalar (the repr of 10**400 is 400 digits, or an error)."""
    if isinstance(v, int) and not isinstance(v, bool) and abs(v) >= 10**30:
        return f"an integer of {v.bit_length()} bits"
    if isinstance(v, (int, float, bool)) or v is None:
        return repr(v)
    return f"a {type(v).__name__}"


# --- frames --------------------------------------------------------------------------------------

_NUMBER_TYPES = (float, int, bool, np.floating, np.integer, np.bool_)


def _frames_array(v: Any, source: str, limits: ClipLimits) -> np.ndarray:
    """frames as float32 [T, W], every dimension checked before a value is converted."""
    if isinstance(v, np.ndarray):
        if v.dtype.kind not in "biuf":
            raise MimicKitError(f"{source}: frames must hold real numbers, got an array of {v.dtype}")
        if v.ndim != 2:
            raise MimicKitError(f"{source}: frames must be [num_frames, 6 + dofs], got shape {v.shape}")
        _check_dims(v.shape[0], v.shape[1], source, limits)
        with np.errstate(over="ignore"):  # beyond float32 is inf, reported as a non-finite column
            return v.astype(np.float32)
    if not isinstance(v, (list, tuple)):
        raise MimicKitError(f"{source}: frames must be a list of frames, got {type(v).__name__}")
    _check_dims(len(v), None, source, limits)
    row_types = set(map(type, v))
    widths = set(map(len, v)) if row_types <= {list, tuple} else set()
    if len(widths) == 1:  # the usual clip, checked at C speed: rows of one length
        width = widths.pop()
        lists = v
    else:  # arrays among the rows, or a row of another length or type: row by row
        width = _row_width(v, source)
        lists = [r for r in v if not isinstance(r, np.ndarray)]
    _check_dims(len(v), width, source, limits)
    _check_leaves(lists, source)
    with np.errstate(over="ignore"):  # every value is a real number now: nothing can expand
        if lists is v:
            return np.fromiter(itertools.chain.from_iterable(v), np.float32, len(v) * width).reshape(len(v), width)
        return np.array(v, dtype=np.float32)


def _check_dims(num_frames: int, width: int | None, source: str, limits: ClipLimits) -> None:
    if num_frames < 1:
        raise MimicKitError(f"{source}: frames is empty; a clip needs at least one frame")
    if num_frames > limits.max_frames:
        raise MimicKitError(
            f"{source}: {num_frames} frames is over the limit of {limits.max_frames}"
            f" (set {env_var_for('max_frames')} to allow more)"
        )
    if width is None:
        return
    if width < 6:
        raise MimicKitError(f"{source}: frames must be [num_frames, 6 + dofs], got {width} values a frame")
    if width > limits.max_frame_width:
        raise MimicKitError(
            f"{source}: {width} values a frame is over the limit of {limits.max_frame_width}"
            f" (set {env_var_for('max_frame_width')} to allow more)"
        )
    if num_frames * width > limits.max_values:
        raise MimicKitError(
            f"{source}: {num_frames} frames x {width} values is over the limit of {limits.max_values} values"
            f" (set {env_var_for('max_values')} to allow more)"
        )


def _row_width(rows: list | tuple, source: str) -> int:
    """The common length of the rows (lists, tuples or 1-D real arrays); one line for the first odd row."""
    width = None
    for i, row in enumerate(rows):
        if isinstance(row, np.ndarray):
            if row.ndim != 1 or row.dtype.kind not in "biuf":
                raise MimicKitError(f"{source}: frames[{i}] must be a row of real numbers, got {row.dtype} {row.shape}")
        elif not isinstance(row, (list, tuple)):
            raise MimicKitError(f"{source}: frames[{i}] must be a list of numbers, got {_describe(row)}")
        if width is None:
            width = len(row)
        elif len(row) != width:
            raise MimicKitError(
                f"{source}: frames must be a 2-D array of numbers with equal-length rows;"
                f" frames[0] has {width} values, frames[{i}] has {len(row)}"
            )
    return width or 0


def _check_leaves(lists: list, source: str) -> None:
    """Every value of every list row is a real number: nothing nested, no None, no complex, no text.

    `sum` is the fast test (C speed, 5x faster than collecting the types): it fails on anything
    that is not a number and gives a complex for complex values. Only then are the rows searched,
    for the first bad value and a message naming it."""
    try:
        total = sum(itertools.chain.from_iterable(lists), 0.0)
    except (TypeError, OverflowError):
        total = None
    if isinstance(total, (float, np.floating)):
        return
    found = _find(lists, lambda x: not isinstance(x, _NUMBER_TYPES) or (isinstance(x, int) and abs(x) > 1e308))
    if found is None:
        raise MimicKitError(f"{source}: frames must hold real numbers only")
    r, c = found
    x = lists[r][c]
    if x is None:
        cols = _all_none_columns(lists)
        where = f"; columns {cols} are None in every frame" if cols else ""
        raise MimicKitError(f"{source}: frames[{r}][{c}] is None, not a number{where}")
    if isinstance(x, int) and not isinstance(x, bool):
        raise MimicKitError(f"{source}: frames[{r}][{c}] is an integer too large for a float")
    if isinstance(x, (complex, np.complexfloating)):
        raise MimicKitError(f"{source}: frames[{r}][{c}] is complex; a clip holds real numbers only")
    if isinstance(x, (list, tuple, dict, np.ndarray)):
        raise MimicKitError(f"{source}: frames[{r}][{c}] is a {type(x).__name__}; frames must be 2-D (rows of numbers)")
    raise MimicKitError(f"{source}: frames[{r}][{c}] is {_describe(x)}, not a number")


def _find(rows: Any, bad: Any) -> tuple[int, int] | None:
    for r, row in enumerate(rows):
        for c, x in enumerate(row):
            if bad(x):
                return r, c
    return None


def _all_none_columns(rows: list) -> list[int]:
    if not rows or len(rows) * len(rows[0]) > 10_000_000:
        return []
    return [c for c in range(len(rows[0])) if all(row[c] is None for row in rows)]


def _nan_columns(frames: np.ndarray) -> tuple[int, ...]:
    return tuple(int(c) for c in np.where(~np.isfinite(frames).all(axis=0))[0])


def _sanitized(motion: Motion, source: str, sanitize_nan: bool) -> Motion:
    if motion.nan_columns and sanitize_nan:
        warn(f"{source}: non-finite values in columns {list(motion.nan_columns)} replaced by 0", stacklevel=3)
        motion.frames = np.nan_to_num(motion.frames, nan=0.0, posinf=0.0, neginf=0.0)
    return motion


def _plain_number(v: float) -> int | float:
    return int(v) if float(v).is_integer() else float(v)


# --- the guarded child ---------------------------------------------------------------------------

_WIRE = struct.Struct("<4sBdIII")  # magic, loop mode, fps, frames, width, NaN columns
_MAGIC = b"MKC1"


def _guarded(target: Any, args: tuple, source: str, limits: ClipLimits, sanitize_nan: bool) -> Motion:
    payload = run_guarded(
        target,
        *args,
        label=source,
        timeout_s=limits.parse_timeout_s,
        memory_mb=limits.parse_memory_mb,
        max_result_bytes=_WIRE.size + 4 * limits.max_values + 4 * limits.max_frame_width,
    )
    return _sanitized(_decode(payload, source, limits), source, sanitize_nan)


def _child_parse_file(path: str, limits: ClipLimits) -> bytes:
    return _encode(_parse_clip(_read_clip_file(Path(path), limits), path, limits))


def _child_parse_bytes(data: bytes, source: str, limits: ClipLimits) -> bytes:
    return _encode(_parse_clip(data, source, limits))


def _encode(m: Motion) -> bytes:
    cols = np.asarray(m.nan_columns, dtype="<u4")
    head = _WIRE.pack(_MAGIC, int(m.loop_mode), m.fps, m.num_frames, m.frame_dim, cols.size)
    return head + cols.tobytes() + np.ascontiguousarray(m.frames, dtype="<f4").tobytes()


def _decode(payload: bytes, source: str, limits: ClipLimits) -> Motion:
    """The child's answer, read as strictly as a file: a broken child cannot hand back a broken clip."""
    try:
        magic, loop, fps, t, w, n = _WIRE.unpack_from(payload)
    except struct.error:
        raise MimicKitError(f"{source}: the parser process sent a malformed result") from None
    size = _WIRE.size + 4 * n + 4 * t * w
    if magic != _MAGIC or loop not in (0, 1) or len(payload) != size or n > w:
        raise MimicKitError(f"{source}: the parser process sent a malformed result")
    _check_dims(t, w, source, limits)
    cols = tuple(int(c) for c in np.frombuffer(payload, "<u4", n, _WIRE.size))
    frames = np.frombuffer(payload, "<f4", t * w, _WIRE.size + 4 * n).reshape(t, w).astype(np.float32)
    return Motion(LoopMode(loop), fps, frames, cols)
