"""MimicKit motion clips: the `.pkl` format, read safely and written byte-compatibly.

A clip is a pickled dict `{"loop_mode": int, "fps": number, "frames": [[...], ...]}` with frames
`[root_pos(3), root_rot exp-map(3), dofs(D)]` per row, loop_mode 0 = clamp, 1 = wrap (spec §4.1).
"""

from __future__ import annotations

import math
import pickle
import struct
import warnings
from dataclasses import dataclass
from enum import IntEnum
from pathlib import Path
from typing import Any

import numpy as np

from mimickit.util.errors import MimicKitError
from mimickit.util.paths import atomic_write_bytes
from mimickit.util.safe_pickle import safe_loads

MAX_CLIP_BYTES = 256 * 1024 * 1024


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


def load_motion(path: str | Path, *, sanitize_nan: bool = True) -> Motion:
    """Read and validate a clip. Errors name the file; NaN columns become 0 with a warning."""
    p = Path(path)
    if not p.is_file():
        raise MimicKitError(f"motion file not found: {p}")
    size = p.stat().st_size
    if size > MAX_CLIP_BYTES:
        raise MimicKitError(f"{p}: {size} bytes is over the {MAX_CLIP_BYTES}-byte limit for a clip")
    return motion_from_bytes(p.read_bytes(), source=str(p), sanitize_nan=sanitize_nan)


def motion_from_bytes(data: bytes, *, source: str = "<bytes>", sanitize_nan: bool = True) -> Motion:
    try:
        obj = safe_loads(data)
    except pickle.UnpicklingError as e:
        raise MimicKitError(f"{source}: not a MimicKit clip ({e})") from None
    except (EOFError, ValueError, TypeError, IndexError, KeyError, AttributeError, struct.error) as e:
        raise MimicKitError(f"{source}: not a MimicKit clip (truncated or corrupt pickle: {e!r})") from None
    return motion_from_dict(obj, source=source, sanitize_nan=sanitize_nan)


def motion_from_dict(obj: Any, *, source: str = "<dict>", sanitize_nan: bool = True) -> Motion:
    if not isinstance(obj, dict):
        raise MimicKitError(f"{source}: expected a dict with loop_mode, fps, frames; got {type(obj).__name__}")
    missing = [k for k in ("loop_mode", "fps", "frames") if k not in obj]
    if missing:
        raise MimicKitError(f"{source}: missing key(s) {', '.join(missing)}")
    loop_mode = _as_number(obj["loop_mode"], source, "loop_mode")
    if loop_mode not in (0, 1):
        raise MimicKitError(f"{source}: loop_mode must be 0 (clamp) or 1 (wrap), got {obj['loop_mode']!r}")
    fps = _as_number(obj["fps"], source, "fps")
    if not math.isfinite(fps) or fps <= 0:
        raise MimicKitError(f"{source}: fps must be a positive number, got {fps!r}")
    try:
        frames = np.array(obj["frames"], dtype=np.float32)
    except (ValueError, TypeError):
        raise MimicKitError(f"{source}: frames must be a 2-D array of numbers with equal-length rows") from None
    if frames.ndim != 2 or frames.shape[0] < 1 or frames.shape[1] < 6:
        raise MimicKitError(f"{source}: frames must be [num_frames, 6 + dofs], got shape {frames.shape}")
    nan_cols = tuple(int(c) for c in np.where(~np.isfinite(frames).all(axis=0))[0])
    if nan_cols and sanitize_nan:
        warnings.warn(f"{source}: non-finite values in columns {list(nan_cols)} replaced by 0", stacklevel=2)
        frames = np.nan_to_num(frames, nan=0.0, posinf=0.0, neginf=0.0)
    return Motion(LoopMode(int(loop_mode)), float(fps), frames, nan_cols)


def save_motion(path: str | Path, motion: Motion) -> None:
    """Write a clip in the reference format: a plain pickled dict of python types (atomic)."""
    atomic_write_bytes(path, pickle.dumps(motion.to_dict()))


def _as_number(v: Any, source: str, key: str) -> float:
    if isinstance(v, np.ndarray) and v.size == 1:
        v = v.reshape(()).item()
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise MimicKitError(f"{source}: {key} must be a number, got {type(v).__name__}")
    return v


def _plain_number(v: float) -> int | float:
    return int(v) if float(v).is_integer() else float(v)
