"""Clip analysis: per-frame curves of what the scene shows, for the page's Analysis box.

For a clip, its every frame; for a rollout, its recorded history (the last `HISTORY_S` seconds), the
simulated character beside its reference (the ghost, with the ghost's drawing offset taken off). Per
frame: the time, the root path, each picked joint's angle and angular velocity, and which feet touch the
ground (the clip player's rule: the foot's lowest collision point within `CONTACT_HEIGHT` of z = 0).

What a joint's "angle" is: a hinge's angle (rad, signed, the clip's DoF value) and its velocity dθ/dt;
a 3-DoF (ball) joint's rotation angle away from its zero pose (rad, in [0, π]: the norm of its exp-map
DoFs) and its angular speed (rad/s, ≥ 0: how fast it turns about any axis), one number each, so every
joint is one curve. Velocities are central differences (one-sided at the ends), never across an
episode's start; a one-frame episode has none (NaN, JSON null).

The scene thread only hands over copies (`ClipPose` is immutable once posed; a rollout's recorded
qpos, steps and episodes); the kinematics and the numpy work run in the caller's thread, on its own
`MjData`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
import torch

from mimickit.anim.kin_char_model import Joint, JointType, KinCharModel
from mimickit.envs.viewable import TracksReference
from mimickit.util import torch_util as tu
from mimickit.util.errors import MimicKitError
from studio.scene.clip_pose import CONTACT_HEIGHT, ClipPose, feet_low_z, foot_bodies
from studio.scene.rollout import Rollout

MAX_JOINTS = 8  # curves per request: a page picks a few; each is 2 × T numbers per figure
DEFAULT_JOINTS = 4  # picked when the request names none: the first hinges (knees, elbows on a humanoid)
DECIMALS = 5


@dataclass(frozen=True)
class Figure:
    """One figure's per-frame values: T frames, J picked joints."""

    root: np.ndarray  # [T, 3] root position
    joints: dict[str, np.ndarray]  # name -> [T] hinge angle, or [T, 4] ball rotation (xyzw)
    foot_low_z: np.ndarray  # [T, F]


@dataclass(frozen=True)
class Recorded:
    """A rollout's history, copied on the scene thread: what the analysis reads of it."""

    model: mujoco.MjModel
    char: KinCharModel
    qpos: np.ndarray  # [T, nq]
    steps: np.ndarray  # [T]
    episodes: np.ndarray  # [T]
    dt: float
    char_bodies: np.ndarray  # [J] MuJoCo body ids of the character, in the kinematic model's order
    ghost_bodies: np.ndarray  # the same of the ghost (empty without one)
    ghost_offset: np.ndarray  # [3] where the ghost is drawn relative to the reference
    source: str


def joint_list(char: KinCharModel) -> list[dict[str, Any]]:
    """The joints one can pick: every non-root joint with DoFs, in body order."""
    return [
        {"name": j.name, "type": "hinge" if j.type == JointType.HINGE else "ball", "dofs": j.dof_dim}
        for j in char.joints[1:]
        if j.type in (JointType.HINGE, JointType.SPHERICAL)
    ]


def pick_joints(char: KinCharModel, names: list[str] | None) -> list[str]:
    """`names` checked against the character (MimicKitError naming an unknown one, or too many); none
    given: the first `DEFAULT_JOINTS` hinges (else the first joints)."""
    known = joint_list(char)
    if not names:
        hinges = [j["name"] for j in known if j["type"] == "hinge"]
        return (hinges or [j["name"] for j in known])[:DEFAULT_JOINTS]
    if len(names) > MAX_JOINTS:
        raise MimicKitError(f"at most {MAX_JOINTS} joints per request, got {len(names)}")
    valid = {j["name"] for j in known}
    for n in names:
        if n not in valid:
            raise MimicKitError(f"no joint {n!r} in the character (its joints: {', '.join(j['name'] for j in known)})")
    return list(dict.fromkeys(names))


def clip_figure(pose: ClipPose, joints: list[str]) -> Figure:
    """The clip's own values: its DoF columns (ball joints' exp-maps as rotations), root and feet."""
    dofs = torch.from_numpy(pose.motion.frames[:, 6:])
    values = {}
    for name in joints:
        j = _joint(pose.char, name)
        col = dofs[:, j.dof_idx : j.dof_idx + j.dof_dim]
        values[name] = col[:, 0].numpy() if j.type == JointType.HINGE else tu.exp_map_to_quat(col).numpy()
    return Figure(pose.root_pos.astype(np.float64), values, pose.foot_low_z)


def record(r: Rollout) -> Recorded:
    """Copies of what the analysis reads of rollout `r` (scene thread: the history grows there)."""
    hist = list(r.history)
    offset = r.env.ref_char_offset if isinstance(r.env, TracksReference) else (0.0, 0.0, 0.0)
    return Recorded(
        model=r.model,
        char=r.env.char_model,
        qpos=np.stack([f.qpos for f in hist]),
        steps=np.array([f.step for f in hist]),
        episodes=np.array([f.episode for f in hist]),
        dt=r.dt,
        char_bodies=np.asarray(r.char_bodies),
        ghost_bodies=np.asarray(r.ghost_bodies),
        ghost_offset=np.asarray(offset, dtype=np.float64),
        source=str(r.source.checkpoint),
    )


def rollout_figure(rec: Recorded, bodies: np.ndarray, joints: list[str], offset: np.ndarray) -> Figure:
    """One figure of a recorded rollout (the character's or the ghost's `bodies`): its joints read from
    the recorded qpos (a hinge's angle; a ball's quaternion, MuJoCo's wxyz), its root and feet posed by
    MuJoCo's kinematics, `offset` taken off the positions."""
    m, char = rec.model, rec.char
    data = mujoco.MjData(m)  # our own: the scene thread draws with the rollout's
    pos = np.empty((len(rec.qpos), len(bodies), 3))
    rot = np.empty((len(rec.qpos), len(bodies), 4))
    for t, q in enumerate(rec.qpos):
        data.qpos[:] = q
        mujoco.mj_kinematics(m, data)
        pos[t] = data.xpos[bodies]
        rot[t] = data.xquat[bodies][:, [1, 2, 3, 0]]  # wxyz -> xyzw
    pos -= offset
    values = {}
    for name in joints:
        j = _joint(char, name)
        adr = int(m.jnt_qposadr[m.body_jntadr[bodies[j.body_id]]])
        values[name] = rec.qpos[:, adr] if j.type == JointType.HINGE else rec.qpos[:, adr : adr + 4][:, [1, 2, 3, 0]]
    low = feet_low_z(char, foot_bodies(char), torch.from_numpy(pos).float(), torch.from_numpy(rot).float())
    return Figure(pos[:, 0], values, low)


def _joint(char: KinCharModel, name: str) -> Joint:
    return next(j for j in char.joints[1:] if j.name == name)


def angle_and_velocity(values: np.ndarray, segments: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """[T] angle and [T] angular velocity of one joint (see the module docstring), velocities within
    each run of equal `segments` (a rollout's episodes) only."""
    if values.ndim == 1:
        return values.astype(np.float64), _within(segments, lambda s: _gradient(values[s], dt))
    q = torch.from_numpy(np.ascontiguousarray(values, dtype=np.float64))
    angle = tu.quat_angle(q).numpy()
    return angle, _within(segments, lambda s: _angular_speed(q[s], dt))


def _gradient(x: np.ndarray, dt: float) -> np.ndarray:
    return np.gradient(x, dt) if len(x) > 1 else np.full(len(x), np.nan)


def _angular_speed(q: torch.Tensor, dt: float) -> np.ndarray:
    """|ω| of a rotation sequence [n, 4]: the angle turned between the neighbours (central), or to the
    one neighbour at the ends."""
    n = len(q)
    if n < 2:
        return np.full(n, np.nan)
    lo = torch.clamp(torch.arange(n) - 1, min=0)
    hi = torch.clamp(torch.arange(n) + 1, max=n - 1)
    return (tu.quat_diff_angle(q[lo], q[hi]) / ((hi - lo).double() * dt)).numpy()


def _within(segments: np.ndarray, fn: Any) -> np.ndarray:
    """`fn(slice)` over each run of equal values in `segments`, joined."""
    out = np.empty(len(segments))
    starts = np.flatnonzero(np.r_[True, segments[1:] != segments[:-1]])
    for a, b in zip(starts, np.r_[starts[1:], len(segments)], strict=True):
        out[a:b] = fn(slice(a, b))
    return out


def figure_json(fig: Figure, feet: list[str], segments: np.ndarray, dt: float) -> dict[str, Any]:
    """One figure's curves as the API gives them (NaN as null)."""
    curves = {n: angle_and_velocity(v, segments, dt) for n, v in fig.joints.items()}
    return {
        "root": {axis: _list(fig.root[:, i]) for i, axis in enumerate("xyz")},
        "angle": {n: _list(a) for n, (a, _) in curves.items()},
        "velocity": {n: _list(v) for n, (_, v) in curves.items()},
        "contacts": {f: (fig.foot_low_z[:, i] <= CONTACT_HEIGHT).tolist() for i, f in enumerate(feet)},
    }


def _list(x: np.ndarray) -> list[float | None]:
    r = np.round(x.astype(np.float64), DECIMALS)
    return [None if not np.isfinite(v) else float(v) for v in r]


def analyse_clip(pose: ClipPose, names: list[str] | None) -> dict[str, Any]:
    """The analysis of a whole clip (see the module docstring)."""
    joints = pick_joints(pose.char, names)
    n, dt = pose.num_frames, 1.0 / pose.fps
    return {
        **_header("clip", str(pose.path), pose.char, joints, pose.feet, dt),
        "time": _list(np.arange(n) * dt),
        "episode": None,
        "char": figure_json(clip_figure(pose, joints), pose.feet, np.zeros(n), dt),
        "ref": None,
    }


def analyse_rollout(rec: Recorded, names: list[str] | None) -> dict[str, Any]:
    """The analysis of a recorded rollout: the character and, when it shows one, its reference."""
    joints = pick_joints(rec.char, names)
    feet = foot_bodies(rec.char)
    sim = rollout_figure(rec, rec.char_bodies, joints, np.zeros(3))
    ref = rollout_figure(rec, rec.ghost_bodies, joints, rec.ghost_offset) if len(rec.ghost_bodies) else None
    return {
        **_header("rollout", rec.source, rec.char, joints, feet, rec.dt),
        "time": _list(rec.steps * rec.dt),
        "episode": rec.episodes.tolist(),
        "char": figure_json(sim, feet, rec.episodes, rec.dt),
        "ref": figure_json(ref, feet, rec.episodes, rec.dt) if ref is not None else None,
    }


def _header(mode: str, source: str, char: KinCharModel, joints: list[str], feet: list[str], dt: float) -> dict:
    return {
        "mode": mode,
        "source": source,
        "fps": 1.0 / dt,
        "joints": joint_list(char),
        "picked": joints,
        "feet": feet,
        "units": {"angle": "rad", "velocity": "rad/s", "root": "m"},
        "measure": "hinge: angle and dθ/dt; ball: rotation angle from the zero pose and angular speed",
    }
