"""Numpy rotation helpers for MuJoCo's w-first quaternions, batched over leading axes: the MuJoCo engine
converts its state with these in plain numpy (torch ops there wake torch's worker threads, which then
compete with the physics threads; see `MujocoEngine._refresh`). Torch twins in xyzw order are in
`torch_util`."""

from __future__ import annotations

import numpy as np


def quat_wxyz_canonical(q: np.ndarray) -> np.ndarray:
    """Quaternions [..., 4] (w first) normalised, with w >= 0."""
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def quat_wxyz_to_exp_map(q: np.ndarray) -> np.ndarray:
    """Canonical quaternions [..., 4] (w first, unit, w >= 0: `quat_wxyz_canonical`) to exp-maps [..., 3]:
    numpy twin of `torch_util.quat_to_exp_map` (the angle is in [0, π], zero near identity)."""
    v = q[..., 1:]
    sin_half = np.linalg.norm(v, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(sin_half, q[..., :1])
    small = sin_half <= 1e-5
    return np.where(small, 0.0, v * (angle / np.where(small, 1.0, sin_half)))


def quat_rotate_wxyz(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate v [n, 3] (or one [3]) by unit quaternions q [n, 4] (w first)."""
    w, u = q[:, :1], q[:, 1:]
    t = 2.0 * cross(u, v)
    return v + w * t + cross(u, t)


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b over the last axis, broadcasting; on small arrays np.cross spends most of its time on
    argument handling (axis moves), several times the arithmetic."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)
