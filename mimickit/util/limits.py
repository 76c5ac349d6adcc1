"""How big and how slow an untrusted clip may be, with the environment variables that raise the limits.

Every limit has a default sized well above the real MimicKit clips (the largest official clip is
1.4 MB, 4,692 frames, 75 columns) and well below what a crafted file needs to hurt a machine.
`ClipLimits.from_env()` reads the overrides; an unreadable override is one error naming the variable.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace

from mimickit.util.errors import MimicKitError

MB = 1024 * 1024


@dataclass(frozen=True)
class ClipLimits:
    """Limits on one `.pkl` clip. Sizes are in MiB ("MB" in messages)."""

    # A file over this is refused before a byte is parsed (MIMICKIT_MAX_CLIP_MB).
    max_file_mb: float = 128.0
    # Frames (rows) of a clip: 100,000 is 55 minutes at 30 fps (MIMICKIT_MAX_FRAMES).
    max_frames: int = 100_000
    # Values per frame: the widest official clip has 75 (MIMICKIT_MAX_FRAME_WIDTH).
    max_frame_width: int = 512
    # Frames x width, and the element count of any one array in the pickle: 20M values is
    # 80 MB as float32 (MIMICKIT_MAX_CLIP_VALUES).
    max_values: int = 20_000_000
    # Estimated memory the unpickled objects may take, checked from the opcodes before unpickling
    # (a Python list of floats costs ~32 bytes a value) (MIMICKIT_MAX_PARSE_MB).
    max_parse_mb: float = 1024.0
    # fps bounds: below 1e-3 a frame lasts over 16 minutes, above 1e4 is faster than any mocap
    # system or simulation step; outside them the number is a corrupt field, not a frame rate.
    min_fps: float = 1e-3
    max_fps: float = 1e4
    # The guarded child process (`load_motion_guarded`): wall-clock budget and memory bound
    # over its start-up footprint (MIMICKIT_PARSE_TIMEOUT_S, MIMICKIT_PARSE_MEMORY_MB).
    parse_timeout_s: float = 5.0
    parse_memory_mb: float = 2048.0

    @property
    def max_file_bytes(self) -> int:
        return int(self.max_file_mb * MB)

    @property
    def max_parse_bytes(self) -> int:
        return int(self.max_parse_mb * MB)

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None) -> ClipLimits:
        """The defaults, with each `MIMICKIT_...` variable that is set replacing its limit."""
        env = os.environ if environ is None else environ
        changes: dict[str, float | int] = {}
        types = {f.name: f.type for f in fields(cls)}
        for var, name in ENV_VARS.items():
            text = env.get(var)
            if text is None or text.strip() == "":
                continue
            changes[name] = _parse_positive(var, text, integer=types[name] in (int, "int"))
        return replace(cls(), **changes) if changes else cls()


ENV_VARS = {
    "MIMICKIT_MAX_CLIP_MB": "max_file_mb",
    "MIMICKIT_MAX_FRAMES": "max_frames",
    "MIMICKIT_MAX_FRAME_WIDTH": "max_frame_width",
    "MIMICKIT_MAX_CLIP_VALUES": "max_values",
    "MIMICKIT_MAX_PARSE_MB": "max_parse_mb",
    "MIMICKIT_PARSE_TIMEOUT_S": "parse_timeout_s",
    "MIMICKIT_PARSE_MEMORY_MB": "parse_memory_mb",
}


def env_var_for(name: str) -> str:
    """The variable that sets limit `name`, for error messages ("" when it has none)."""
    for var, field_name in ENV_VARS.items():
        if field_name == name:
            return var
    return ""


def _parse_positive(var: str, text: str, *, integer: bool) -> float | int:
    try:
        value = int(text) if integer else float(text)
    except ValueError:
        kind = "a whole number" if integer else "a number"
        raise MimicKitError(f"{var}={text[:40]!r} is not {kind}") from None
    if not (math.isfinite(value) and value > 0):
        raise MimicKitError(f"{var}={text[:40]!r} must be a positive number")
    return value
