"""Convert DeepMimic `humanoid3d` text clips into MimicKit humanoid clips.

DeepMimic text format (``data/motions/humanoid3d_*.txt``): JSON ``{"Loop": "wrap"|"none", "Frames": [...]}``
with 44 numbers per frame::

    [dt, root_pos(3), root_rot(4), chest(4), neck(4), right_hip(4), right_knee(1), right_ankle(4),
     right_shoulder(4), right_elbow(1), left_hip(4), left_knee(1), left_ankle(4), left_shoulder(4),
     left_elbow(1)]

quaternions w-first, a Y-up world, ``dt`` = time from this frame to the next (the last one is ignored,
it is usually 0). MimicKit humanoid frame (the `.pkl` layout of `mimickit.anim.motion` on
``data/assets/humanoid/humanoid.xml``): ``[root_pos(3), root_rot exp-map(3), abdomen(3),
neck(3), right_shoulder(3), right_elbow(1), left_shoulder(3), left_elbow(1), right_hip(3), right_knee(1),
right_ankle(3), left_hip(3), left_knee(1), left_ankle(3)]`` in a Z-up world.

How the frames map (derived from ``characters/humanoid3d.txt`` against the MimicKit ``humanoid.xml``,
and confirmed by forward kinematics against the official MimicKit clips of the same takes):

* World and body frames: ``C = R_x(+90°)``, i.e. DeepMimic ``(x, y, z)`` → MimicKit ``(x, -z, y)``.
  Every DeepMimic joint offset maps onto the MimicKit body offset under C (right hip at DeepMimic +z
  = MimicKit -y, spine along +y = +z). So root position ``p' = C p``, and the root and every
  spherical joint rotation is conjugated: ``q' = C q C⁻¹``.
* Shoulders: DeepMimic's zero pose has the arms hanging down, MimicKit's is a T-pose (upper arm along
  -y / +y). The MimicKit upper-arm frame is the DeepMimic one turned by ``A_r = R_x(+90°)`` (right) /
  ``A_l = R_x(-90°)`` (left), so the shoulder rotation is ``q' = (C q C⁻¹) ⊗ A``. The same ``A`` makes
  the lower-arm frames line up, so no correction is needed below the elbow.
* Hinges: DeepMimic knees and elbows turn about local z. Under C the knee axis becomes -y (MimicKit
  knee axis +y) → ``knee' = -knee``. Under A the elbow axis becomes +z on the right (same sign) and
  -z on the left → ``right_elbow' = right_elbow``, ``left_elbow' = -left_elbow``.
* 3-DoF joints are stored as exponential maps (quaternion forced to w ≥ 0, angle in [0, π]).

Timing: fps = 1 / median(dt) over all but the last frame, snapped to the nearest integer when within
0.1 % (the text files store dt with six decimals, 0.016666 → 60.0024). If the dts differ from the
median by more than 1 %, the clip is resampled at that uniform rate (root position and hinge angles
lerped, rotations slerped) unless ``resample=False``. ``"Loop": "wrap"`` → LoopMode.WRAP,
``"none"`` → LoopMode.CLAMP.

    python -m mimickit.tools.deepmimic_convert humanoid3d_backflip.txt humanoid_backflip.pkl
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

import mimickit.util.torch_util as tu
from mimickit.anim.kin_char_model import KinCharModel
from mimickit.anim.motion import MAX_CLIP_BYTES, LoopMode, Motion, save_motion
from mimickit.util.errors import MimicKitError

DM_FRAME_WIDTH = 44
MK_FRAME_WIDTH = 34
DT_TOLERANCE = 0.01  # relative spread of frame durations beyond which a clip is resampled
FPS_SNAP_TOLERANCE = 1e-3  # relative distance to an integer fps that is snapped to it

_LOOP_MODES = {"wrap": LoopMode.WRAP, "none": LoopMode.CLAMP}

# Column of each DeepMimic quantity in a 44-wide frame (after dt at column 0).
_ROOT_POS = 1
_ROOT_ROT = 4
_QUATS = {  # spherical joints: first column of the w x y z quaternion
    "chest": 8,
    "neck": 12,
    "right_hip": 16,
    "right_ankle": 21,
    "right_shoulder": 25,
    "left_hip": 30,
    "left_ankle": 35,
    "left_shoulder": 39,
}
_HINGES = {"right_knee": 20, "right_elbow": 29, "left_knee": 34, "left_elbow": 43}
_HINGE_SIGN = {"right_knee": -1.0, "left_knee": -1.0, "right_elbow": 1.0, "left_elbow": -1.0}
# MimicKit dof layout: (DeepMimic joint, dof width) in MimicKit order.
_MK_LAYOUT = [
    ("chest", 3),  # abdomen
    ("neck", 3),
    ("right_shoulder", 3),
    ("right_elbow", 1),
    ("left_shoulder", 3),
    ("left_elbow", 1),
    ("right_hip", 3),
    ("right_knee", 1),
    ("right_ankle", 3),
    ("left_hip", 3),
    ("left_knee", 1),
    ("left_ankle", 3),
]


def _expmap_columns() -> list[int]:
    cols, c = [3], 6  # root rotation, then the 3-wide joints of the layout
    for _, width in _MK_LAYOUT:
        if width == 3:
            cols.append(c)
        c += width
    return cols


MK_EXPMAP_COLUMNS = _expmap_columns()  # first column of each exponential map in a MimicKit frame (resampling)

_HALF = math.sqrt(0.5)
_C = (_HALF, 0.0, 0.0, _HALF)  # R_x(+90°), x y z w: DeepMimic y-up → MimicKit z-up
_SHOULDER_OFFSET = {"right_shoulder": (_HALF, 0.0, 0.0, _HALF), "left_shoulder": (-_HALF, 0.0, 0.0, _HALF)}


@dataclass
class DeepMimicClip:
    """A parsed DeepMimic text clip: loop mode and the raw float64 frames [T, 44]."""

    loop_mode: LoopMode
    frames: np.ndarray
    source: str

    @property
    def dts(self) -> np.ndarray:
        return self.frames[:, 0]


def load_deepmimic_text(path: str | Path) -> DeepMimicClip:
    """Read and validate a DeepMimic humanoid3d motion file; every error is a MimicKitError naming it."""
    p = Path(path)
    if not p.is_file():
        raise MimicKitError(f"DeepMimic motion file not found: {p}")
    size = p.stat().st_size
    if size > MAX_CLIP_BYTES:
        raise MimicKitError(f"{p}: {size} bytes is over the {MAX_CLIP_BYTES}-byte limit for a clip")
    try:
        obj = json.loads(p.read_bytes().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise MimicKitError(f"{p}: not a DeepMimic motion file (not JSON: {e})") from None
    return deepmimic_from_dict(obj, source=str(p))


def deepmimic_from_dict(obj: object, *, source: str = "<dict>") -> DeepMimicClip:
    if not isinstance(obj, dict):
        raise MimicKitError(f"{source}: expected a JSON object with Loop and Frames, got {type(obj).__name__}")
    missing = [k for k in ("Loop", "Frames") if k not in obj]
    if missing:
        raise MimicKitError(f"{source}: missing key(s) {', '.join(missing)}")
    loop = obj["Loop"]
    if not isinstance(loop, str) or loop.lower() not in _LOOP_MODES:
        raise MimicKitError(f'{source}: Loop must be "wrap" or "none", got {loop!r}')
    rows = obj["Frames"]
    if not isinstance(rows, list) or not rows:
        raise MimicKitError(f"{source}: Frames must be a non-empty list of frames")
    for i, row in enumerate(rows):
        if not isinstance(row, list) or len(row) != DM_FRAME_WIDTH:
            width = len(row) if isinstance(row, list) else type(row).__name__
            raise MimicKitError(
                f"{source}: frame {i} has width {width}, a humanoid3d frame has {DM_FRAME_WIDTH} numbers"
            )
        if any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in row):
            raise MimicKitError(f"{source}: frame {i} holds a value that is not a number")
    frames = np.asarray(rows, dtype=np.float64)
    bad = np.where(~np.isfinite(frames).all(axis=1))[0]
    if bad.size:
        raise MimicKitError(f"{source}: frame {int(bad[0])} holds a non-finite value")
    if len(frames) < 2:
        raise MimicKitError(f"{source}: a clip needs at least 2 frames, got {len(frames)}")
    if (frames[:, 0] < 0).any():
        raise MimicKitError(f"{source}: frame {int(np.argmax(frames[:, 0] < 0))} has a negative duration")
    for name, c in {"root": _ROOT_ROT, **_QUATS}.items():
        norms = np.linalg.norm(frames[:, c : c + 4], axis=1)
        if (norms < 1e-6).any():
            raise MimicKitError(f"{source}: frame {int(np.argmax(norms < 1e-6))} has a zero {name} quaternion")
    return DeepMimicClip(_LOOP_MODES[loop.lower()], frames, source)


def clip_fps(dts: np.ndarray) -> tuple[float, bool]:
    """(uniform fps, whether the frame durations are uneven enough to need resampling).

    `dts` are the durations of all frames but the last (the last frame's dt is not a duration)."""
    positive = dts[dts > 0]
    if positive.size == 0:
        raise ValueError("no positive frame duration")
    median = float(np.median(positive))
    fps = 1.0 / median
    if abs(fps - round(fps)) <= FPS_SNAP_TOLERANCE * fps:
        fps = float(round(fps))
    uneven = bool(np.any(np.abs(dts - median) > DT_TOLERANCE * median))
    return fps, uneven


def resample_deepmimic_frames(frames: np.ndarray, fps: float) -> np.ndarray:
    """Resample DeepMimic frames [T, 44] (times from their dts) at a uniform `fps`.

    Root position and hinge angles are lerped, quaternions slerped (shortest path); dt is set to 1/fps
    (0 on the last frame, as in DeepMimic files)."""
    times = np.concatenate([[0.0], np.cumsum(frames[:-1, 0])])
    duration = float(times[-1])
    n = int(round(duration * fps)) + 1
    t = np.minimum(np.arange(n) / fps, duration)
    # Interval [times[i0], times[i0 + 1]] holding each sample; zero-length intervals never get picked.
    i0 = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2)
    i1 = i0 + 1
    span = times[i1] - times[i0]
    blend = np.where(span > 0, (t - times[i0]) / np.where(span > 0, span, 1.0), 0.0)
    blend = np.clip(blend, 0.0, 1.0)
    a, b = frames[i0], frames[i1]
    out = a + (b - a) * blend[:, None]  # root position and hinges (quaternion columns overwritten below)
    bt = torch.from_numpy(blend)
    for c in [_ROOT_ROT, *_QUATS.values()]:
        qa = tu.quat_normalize(tu.quat_from_wxyz(torch.from_numpy(a[:, c : c + 4])))
        qb = tu.quat_normalize(tu.quat_from_wxyz(torch.from_numpy(b[:, c : c + 4])))
        out[:, c : c + 4] = tu.quat_to_wxyz(tu.slerp(qa, qb, bt)).numpy()
    out[:, 0] = 1.0 / fps
    out[-1, 0] = 0.0
    return out


def deepmimic_to_mimickit_frames(frames: np.ndarray) -> np.ndarray:
    """Pose conversion only: DeepMimic frames [T, 44] → MimicKit humanoid frames [T, 34] (float64)."""
    f = torch.as_tensor(np.asarray(frames, dtype=np.float64))
    if f.ndim != 2 or f.shape[1] != DM_FRAME_WIDTH:
        raise ValueError(f"expected DeepMimic frames [T, {DM_FRAME_WIDTH}], got {tuple(f.shape)}")
    T = f.shape[0]
    C = torch.tensor(_C, dtype=f.dtype).expand(T, 4)
    C_inv = tu.quat_conjugate(C)

    def rot(col: int) -> torch.Tensor:  # DeepMimic w-first quaternion → MimicKit frame, x y z w
        q = tu.quat_normalize(tu.quat_from_wxyz(f[:, col : col + 4]))
        return tu.quat_mul(tu.quat_mul(C, q), C_inv)

    root_pos = tu.quat_rotate(C, f[:, _ROOT_POS : _ROOT_POS + 3])
    parts = [root_pos, tu.quat_to_exp_map(rot(_ROOT_ROT))]
    for name, width in _MK_LAYOUT:
        if width == 1:
            parts.append(_HINGE_SIGN[name] * f[:, _HINGES[name], None])
            continue
        q = rot(_QUATS[name])
        if name in _SHOULDER_OFFSET:
            q = tu.quat_mul(q, torch.tensor(_SHOULDER_OFFSET[name], dtype=f.dtype).expand(T, 4))
        parts.append(tu.quat_to_exp_map(q))
    out = torch.cat(parts, dim=-1)
    assert out.shape[1] == MK_FRAME_WIDTH
    return out.numpy()


def convert_deepmimic_clip(clip: DeepMimicClip, *, resample: bool = True) -> Motion:
    try:
        fps, uneven = clip_fps(clip.dts[:-1])
    except ValueError:
        raise MimicKitError(f"{clip.source}: every frame duration (dt) is 0, no frame rate") from None
    frames = clip.frames
    if uneven and resample:
        frames = resample_deepmimic_frames(frames, fps)
    mk = deepmimic_to_mimickit_frames(frames)
    return Motion(clip.loop_mode, fps, mk.astype(np.float32))


def convert_deepmimic(path: str | Path, *, resample: bool = True) -> Motion:
    """A DeepMimic humanoid3d text clip as a MimicKit humanoid Motion (34-wide frames, z-up).

    With `resample=False` uneven frame durations are ignored (frames kept one per 1/fps), which is what
    the official MimicKit conversion of `humanoid3d_roll` did."""
    return convert_deepmimic_clip(load_deepmimic_text(path), resample=resample)


def fk_body_pos(char: KinCharModel, frames: np.ndarray) -> torch.Tensor:
    """World body positions [T, J, 3] (float64) of MimicKit frames [T, 6 + D] on `char`."""
    f = torch.as_tensor(np.asarray(frames, dtype=np.float64))
    root_rot = tu.exp_map_to_quat(f[:, 3:6])
    joint_rot = char.dof_to_rot(f[:, 6:])
    return char.forward_kinematics(f[:, :3], root_rot, joint_rot)[0]


def fk_body_distance(char: KinCharModel, frames_a: np.ndarray, frames_b: np.ndarray) -> torch.Tensor:
    """Per-frame, per-body distance [T, J] (m) between two equally long clips on `char`."""
    if len(frames_a) != len(frames_b):
        raise ValueError(f"clips differ in length: {len(frames_a)} vs {len(frames_b)} frames")
    return (fk_body_pos(char, frames_a) - fk_body_pos(char, frames_b)).norm(dim=-1)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Convert a DeepMimic humanoid3d .txt clip to a MimicKit .pkl")
    ap.add_argument("input", help="DeepMimic motion file (humanoid3d_*.txt)")
    ap.add_argument("output", help="MimicKit clip to write (.pkl)")
    ap.add_argument("--no_resample", action="store_true", help="keep frames as they are even if dts vary")
    args = ap.parse_args(argv)
    try:
        motion = convert_deepmimic(args.input, resample=not args.no_resample)
        save_motion(args.output, motion)
    except MimicKitError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    print(f"{args.output}: {motion.num_frames} frames at {motion.fps:g} fps, {motion.loop_mode.name.lower()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
