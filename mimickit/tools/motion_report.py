"""What `mimickit motion info` and `validate` say about a clip.

The character model (and with it torch) is imported only when a character is given, so checking
clips alone starts in a fraction of a second.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mimickit.anim.motion import Motion, load_motion
from mimickit.util.errors import MimicKitError

if TYPE_CHECKING:
    from mimickit.anim.kin_char_model import KinCharModel


def dof_names(char: KinCharModel) -> list[str]:
    from mimickit.anim.kin_char_model import JointType

    names = []
    for joint in char.joints[1:]:
        if joint.type == JointType.SPHERICAL:
            names += [f"{joint.name}_{a}" for a in "xyz"]
        elif joint.type == JointType.HINGE:
            names.append(joint.name)
    return names


def limit_violations(motion: Motion, char: KinCharModel, tol: float = 1e-3) -> list[dict[str, Any]]:
    """Per DoF outside the character's ranges: name, frames outside, worst excess (rad)."""
    low, high = char.dof_limits()
    dofs = motion.frames[:, 6:].astype(np.float64)
    excess = np.maximum(dofs - high, low - dofs)
    out = []
    for d, name in enumerate(dof_names(char)):
        bad = excess[:, d] > tol
        if bad.any():
            out.append({"dof": name, "frames": int(bad.sum()), "max_excess": round(float(excess[:, d].max()), 4)})
    return out


def motion_info(path: str | Path, char: KinCharModel | None = None) -> dict[str, Any]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = load_motion(path)
    info: dict[str, Any] = {
        "path": str(path),
        "fps": int(m.fps) if float(m.fps).is_integer() else m.fps,
        "loop_mode": m.loop_mode.name.lower(),
        "num_frames": m.num_frames,
        "duration": round(m.duration, 6),
        "frame_dim": m.frame_dim,
        "nan_columns": list(m.nan_columns),
    }
    if char is not None:
        check_frame_dim(m, char, path)
        info["char"] = char.source
        info["limit_violations"] = limit_violations(m, char)
    return info


def check_frame_dim(m: Motion, char: KinCharModel, path: str | Path) -> None:
    need = 6 + char.get_dof_size()
    if m.frame_dim != need:
        raise MimicKitError(
            f"{path}: frames have {m.frame_dim} columns but {char.source} needs {need} (6 + {char.get_dof_size()} DoFs)"
        )


def validate_motion(path: str | Path, char: KinCharModel | None = None) -> tuple[list[str], list[str]]:
    """(problems, warnings) of one clip; no problems means it is valid.

    A clip that does not load is one problem (the loader's line: bad pickle, over a limit, fps
    outside 0.001..10000, complex or None values, ...). Of a loaded clip, non-finite values are
    problems too: the trainer reads them as 0, which is not the motion (the official
    `humanoid_walk.pkl` has NaN neck columns, so it is reported).
    """
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            m = load_motion(path, sanitize_nan=False)
    except MimicKitError as e:
        return [str(e)], []
    problems = non_finite_problems(m, path)
    if m.num_frames < 2:
        problems.append(f"{path}: only {m.num_frames} frame(s); a clip needs at least 2")
    if char is not None:
        try:
            check_frame_dim(m, char, path)
        except MimicKitError as e:
            problems.append(str(e))
    return problems, []


def non_finite_problems(m: Motion, path: str | Path) -> list[str]:
    """One line for the columns with no finite value at all, one for those with some NaN/inf."""
    finite = np.isfinite(m.frames)
    if finite.all():
        return []
    none_finite = [int(c) for c in np.where(~finite.any(axis=0))[0]]
    some = [int(c) for c in np.where(~finite.all(axis=0) & finite.any(axis=0))[0]]
    out = []
    if none_finite:
        kind = "NaN" if np.isnan(m.frames[:, none_finite]).all() else "NaN or infinite"
        out.append(f"{path}: columns {none_finite} are {kind} in every frame (read as 0 when training)")
    if some:
        bad = int((~finite[:, some]).sum())
        out.append(f"{path}: {bad} non-finite values (NaN or infinite) in columns {some} (read as 0 when training)")
    return out


def format_info(info: dict[str, Any]) -> str:
    lines = [
        f"{info['path']}",
        f"  fps {info['fps']:g}, loop {info['loop_mode']}, {info['num_frames']} frames, "
        f"{info['duration']:.3f} s, frame width {info['frame_dim']}",
    ]
    if info["nan_columns"]:
        lines.append(f"  NaN columns {info['nan_columns']} (read as 0)")
    if "limit_violations" in info:
        v = info["limit_violations"]
        if not v:
            lines.append("  all joint values inside the character's limits")
        for row in v:
            lines.append(f"  {row['dof']}: {row['frames']} frames outside limits, worst by {row['max_excess']} rad")
    return "\n".join(lines)
