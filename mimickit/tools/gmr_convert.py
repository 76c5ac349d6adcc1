"""Convert robot motions retargeted by GMR (General Motion Retargeting) into MimicKit clips.

GMR saves a pickle (some forks an `.npz`) with `fps`, `root_pos` [T, 3], `root_rot` [T, 4] and
`dof_pos` [T, D] (plus `local_body_pos`, `link_body_list`, unused here). `root_rot` is x y z w: GMR
writes MuJoCo's w-first `qpos[3:7]` reordered `[1, 2, 3, 0]` (MimicKit's `gmr_to_mimickit` reads it
so too); `root_rot_order="wxyz"` takes files that kept MuJoCo's order. `dof_pos` is MuJoCo's qpos
order of the robot's hinges, which is the MimicKit character's DoF order for the same MJCF (both walk
the bodies depth first). Frames are `[root_pos, exp-map(root_rot), dof_pos]`.

The pickle is read by the restricted unpickler of clips (numpy arrays and plain data only).
"""

from __future__ import annotations

import math
import pickle
import struct
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mimickit.anim.kin_char_model import KinCharModel
from mimickit.anim.motion import MAX_CLIP_BYTES, LoopMode, Motion
from mimickit.util import torch_util as tu
from mimickit.util.errors import MimicKitError
from mimickit.util.safe_pickle import safe_loads

GMR_KEYS = ("fps", "root_pos", "root_rot", "dof_pos")


def load_gmr(path: str | Path) -> dict[str, Any]:
    """The dict of a GMR file (`.pkl` through the restricted unpickler, or `.npz` without pickle)."""
    p = Path(path)
    if not p.is_file():
        raise MimicKitError(f"GMR motion file not found: {p}")
    if p.stat().st_size > MAX_CLIP_BYTES:
        raise MimicKitError(f"{p}: {p.stat().st_size} bytes is over the {MAX_CLIP_BYTES}-byte limit for a clip")
    if p.suffix == ".npz":
        try:
            with np.load(p, allow_pickle=False) as data:
                return {k: np.asarray(data[k]) for k in GMR_KEYS if k in data.files}
        except (OSError, ValueError, zipfile.BadZipFile) as e:
            raise MimicKitError(f"{p}: not a readable GMR .npz file ({e})") from None
    try:
        obj = safe_loads(p.read_bytes())
    except pickle.UnpicklingError as e:
        raise MimicKitError(f"{p}: not a GMR motion pickle ({e})") from None
    except (EOFError, ValueError, TypeError, IndexError, KeyError, AttributeError, struct.error) as e:
        raise MimicKitError(f"{p}: not a GMR motion pickle (truncated or corrupt: {e!r})") from None
    if not isinstance(obj, dict):
        raise MimicKitError(f"{p}: expected a dict with {', '.join(GMR_KEYS)}; got {type(obj).__name__}")
    return obj


def gmr_to_motion(
    obj: dict[str, Any],
    *,
    source: str = "<dict>",
    char: KinCharModel | None = None,
    root_rot_order: str = "xyzw",
    loop_mode: LoopMode = LoopMode.WRAP,
) -> Motion:
    """A GMR dict as a MimicKit Motion; `char` (when given) must have `dof_pos`'s width of DoFs."""
    missing = [k for k in GMR_KEYS if k not in obj]
    if missing:
        raise MimicKitError(f"{source}: missing key '{missing[0]}' (a GMR motion has {', '.join(GMR_KEYS)})")
    fps = _fps(obj["fps"], source)
    root_pos = _array(obj, "root_pos", source)
    root_rot = _array(obj, "root_rot", source)
    dof_pos = _array(obj, "dof_pos", source)
    counts = {"root_pos": root_pos.shape[0], "root_rot": root_rot.shape[0], "dof_pos": dof_pos.shape[0]}
    if len(set(counts.values())) > 1:
        listed = ", ".join(f"'{k}' {n}" for k, n in counts.items())
        raise MimicKitError(f"{source}: the keys disagree on the number of frames ({listed})")
    T = root_pos.shape[0]
    for key, a, width in (("root_pos", root_pos, 3), ("root_rot", root_rot, 4)):
        if a.shape != (T, width):
            raise MimicKitError(f"{source}: key '{key}' has shape {a.shape}; expected ({T}, {width})")
    if dof_pos.ndim != 2 or dof_pos.shape[0] != T:
        raise MimicKitError(f"{source}: key 'dof_pos' has shape {dof_pos.shape}; expected ({T}, DoFs)")
    if T < 2:
        raise MimicKitError(f"{source}: key 'root_pos' has {T} frame(s); a clip needs at least 2")
    if char is not None and dof_pos.shape[1] != char.get_dof_size():
        raise MimicKitError(
            f"{source}: key 'dof_pos' has {dof_pos.shape[1]} DoFs per frame; {char.source} has {char.get_dof_size()}"
        )
    norms = np.linalg.norm(root_rot, axis=1)
    if (norms < 1e-6).any():
        raise MimicKitError(f"{source}: key 'root_rot' has a zero quaternion in frame {int(np.argmax(norms < 1e-6))}")
    q = torch.from_numpy(root_rot / norms[:, None])
    if root_rot_order == "wxyz":
        q = tu.quat_from_wxyz(q)
    elif root_rot_order != "xyzw":
        raise ValueError(f"root_rot_order must be 'xyzw' or 'wxyz', got {root_rot_order!r}")
    frames = np.concatenate([root_pos, tu.quat_to_exp_map(q).numpy(), dof_pos], axis=1)
    return Motion(loop_mode, fps, frames.astype(np.float32))


def _array(obj: dict[str, Any], key: str, source: str) -> np.ndarray:
    try:
        a = np.asarray(obj[key], dtype=np.float64)
    except (TypeError, ValueError):
        raise MimicKitError(f"{source}: key '{key}' is not an array of numbers") from None
    if a.ndim != 2:
        raise MimicKitError(f"{source}: key '{key}' has shape {a.shape}; expected [frames, values]")
    if not np.isfinite(a).all():
        raise MimicKitError(f"{source}: key '{key}' holds a non-finite value")
    return a


def _fps(value: Any, source: str) -> float:
    try:
        a = np.asarray(value, dtype=np.float64)  # GMR writes a number, some forks np.array([fps])
    except (TypeError, ValueError):
        a = np.zeros(0)
    if a.size != 1 or not math.isfinite(float(a.reshape(-1)[0])) or float(a.reshape(-1)[0]) <= 0:
        raise MimicKitError(f"{source}: key 'fps' must be one positive number, got {value!r}")
    return float(a.reshape(-1)[0])
