"""Resample a clip at another frame rate, keeping its duration.

MimicKit's converters only relabel `fps` (the motion then plays faster or slower). Here the frames
are re-sampled: root position and hinge angles are interpolated linearly, the root rotation and
every 3-DoF joint (exponential maps) by quaternion slerp along the shortest path.

Frame count: a clip of T frames at `fps_in` lasts (T − 1) / fps_in seconds; the resampled clip has
N = ⌊duration · fps_out + ½⌋ + 1 frames, sampled at t = k / fps_out, except the last one, which is
the input's last frame (a clip keeps its end pose). Its duration (N − 1) / fps_out equals the input's
when duration · fps_out is a whole number (121 frames at 120 fps → 31 at 30 fps, both 1 s) and is
otherwise within half an output frame of it.
"""

from __future__ import annotations

import numpy as np
import torch

from mimickit.anim.kin_char_model import JointType, KinCharModel
from mimickit.anim.motion import Motion
from mimickit.util import torch_util as tu

ROOT_ROT_COL = 3  # frames are [root_pos(3), root_rot exp-map(3), dofs]


def char_expmap_columns(char: KinCharModel) -> list[int]:
    """First frame column of every exponential map in `char`'s frames: the root's and each 3-DoF joint's."""
    return [ROOT_ROT_COL] + [6 + j.dof_idx for j in char.joints[1:] if j.type == JointType.SPHERICAL]


def resampled_length(num_frames: int, fps_in: float, fps_out: float) -> int:
    """N: the number of frames the clip has at `fps_out` (see the module docstring)."""
    duration = (num_frames - 1) / fps_in
    return int(np.floor(duration * fps_out + 0.5 + 1e-9)) + 1  # half up, not to even


def resample_frames(frames: np.ndarray, fps_in: float, fps_out: float, expmap_cols: list[int]) -> np.ndarray:
    """Frames [T, W] at `fps_in` → [N, W] at `fps_out`; `expmap_cols` are the first columns of the
    exponential-map triples (slerped), every other column is interpolated linearly."""
    if fps_in <= 0 or fps_out <= 0:
        raise ValueError(f"frame rates must be positive, got {fps_in} and {fps_out}")
    f = np.asarray(frames, dtype=np.float64)
    T = f.shape[0]
    if T < 2:
        return f.copy()
    duration = (T - 1) / fps_in
    n = resampled_length(T, fps_in, fps_out)
    t = np.minimum(np.arange(n) / fps_out, duration)
    t[-1] = duration
    pos = t * fps_in  # fractional input frame of each output frame
    i0 = np.minimum(np.floor(pos).astype(np.int64), T - 2)
    blend = np.clip(pos - i0, 0.0, 1.0)
    a, b = f[i0], f[i0 + 1]
    out = a + (b - a) * blend[:, None]
    w = torch.from_numpy(blend)
    for c in expmap_cols:
        qa = tu.exp_map_to_quat(torch.from_numpy(a[:, c : c + 3]))
        qb = tu.exp_map_to_quat(torch.from_numpy(b[:, c : c + 3]))
        out[:, c : c + 3] = tu.quat_to_exp_map(tu.quat_pos(tu.slerp(qa, qb, w))).numpy()
    return out


def resample_motion(motion: Motion, fps: float, expmap_cols: list[int]) -> Motion:
    """`motion` at `fps` (itself when the rate is already `fps`)."""
    if abs(motion.fps - fps) <= 1e-9 * fps:
        return motion
    frames = resample_frames(motion.frames, motion.fps, fps, expmap_cols)
    return Motion(motion.loop_mode, fps, frames.astype(np.float32))
