"""Build a `KinCharModel` from an MJCF file, reading MuJoCo's compiled model.

Rules (the reference's MJCF reader's, made stricter where it silently misreads a file):
- the root is the first body under `<worldbody>`; its joint is ROOT whatever it is;
- a non-root body with no joint is FIXED; one hinge is a HINGE; one ball joint or three hinges about
  x, y, z are one SPHERICAL joint (named after the first hinge up to its last `_`);
- any other joint combination, a slide joint, or a joint with a non-zero `pos` is an error that names
  the body.
PD gains come from the joints' `stiffness`/`damping`, torque limits from `actuatorfrcrange` (else the
gear of a motor on the joint).
"""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import torch

from mimickit.anim.kin_char_model import Joint, JointType, KinCharModel
from mimickit.anim.mjcf_loader import load_mjcf_model
from mimickit.util.errors import MimicKitError

_HINGE = mujoco.mjtJoint.mjJNT_HINGE
_BALL = mujoco.mjtJoint.mjJNT_BALL


def load_char_model(path: str | Path, device: torch.device | str = "cpu") -> KinCharModel:
    model = load_mjcf_model(path)
    return char_model_from_mj(model, path, device)


def char_model_from_mj(m: mujoco.MjModel, source: str | Path, device: torch.device | str = "cpu") -> KinCharModel:
    if m.nbody < 2:
        raise MimicKitError(f"{source}: no body under <worldbody>")
    bodies = _subtree(m, 1)
    index = {b: i for i, b in enumerate(bodies)}
    names, parents, local_pos, local_rot, joints, masses = [], [], [], [], [], []
    dof = 0
    for i, b in enumerate(bodies):
        names.append(m.body(b).name or f"body{b}")
        parents.append(-1 if i == 0 else index[int(m.body_parentid[b])])
        local_pos.append(m.body_pos[b].copy())
        w, x, y, z = m.body_quat[b]
        local_rot.append(np.array([x, y, z, w]) / np.linalg.norm([x, y, z, w]))
        masses.append(float(m.body_mass[b]))
        if i == 0:
            joints.append(Joint(name=names[0], type=JointType.ROOT, body_id=0, dof_idx=0))
            continue
        joint = _body_joint(m, b, i, dof, source)
        joints.append(joint)
        dof += joint.dof_dim
    return KinCharModel(
        body_names=names,
        parent_ids=parents,
        local_pos=np.array(local_pos),
        local_rot=np.array(local_rot),
        joints=joints,
        body_mass=np.array(masses),
        source=source,
        device=device,
    )


def _subtree(m: mujoco.MjModel, root: int) -> list[int]:
    out = [root]
    for b in range(root + 1, m.nbody):
        if int(m.body_parentid[b]) in out:
            out.append(b)
    return out


def _body_joint(m: mujoco.MjModel, b: int, body_idx: int, dof_idx: int, source: str | Path) -> Joint:
    body_name = m.body(b).name
    jids = list(range(m.body_jntadr[b], m.body_jntadr[b] + m.body_jntnum[b]))
    for j in jids:
        if np.any(np.abs(m.jnt_pos[j]) > 1e-9):
            raise MimicKitError(f"{source}: joint '{m.joint(j).name}' of body '{body_name}' has a non-zero pos")
    types = [int(m.jnt_type[j]) for j in jids]
    if not jids:
        return Joint(name=body_name, type=JointType.FIXED, body_id=body_idx, dof_idx=dof_idx)
    if types == [_HINGE]:
        j = jids[0]
        axis = m.jnt_axis[j] / np.linalg.norm(m.jnt_axis[j])
        return _with_dof_params(
            Joint(m.joint(j).name, JointType.HINGE, body_idx, dof_idx, axis=axis, mjcf_joints=[m.joint(j).name]),
            m,
            jids,
        )
    if types == [_BALL]:
        j = jids[0]
        return _with_dof_params(
            Joint(m.joint(j).name, JointType.SPHERICAL, body_idx, dof_idx, mjcf_joints=[m.joint(j).name]), m, jids
        )
    if types == [_HINGE] * 3:
        axes = np.array([m.jnt_axis[j] / np.linalg.norm(m.jnt_axis[j]) for j in jids])
        if not np.allclose(axes, np.eye(3), atol=1e-6):
            raise MimicKitError(f"{source}: body '{body_name}' has three hinges whose axes are not x, y, z in order")
        first = m.joint(jids[0]).name
        name = first[: first.rfind("_")] if "_" in first else first
        joint = Joint(name, JointType.SPHERICAL, body_idx, dof_idx, mjcf_joints=[m.joint(j).name for j in jids])
        return _with_dof_params(joint, m, jids)
    kinds = ", ".join(mujoco.mjtJoint(t).name for t in types)
    raise MimicKitError(
        f"{source}: body '{body_name}' has joints ({kinds}); supported are none, one hinge, one ball, "
        "or three hinges about x, y, z"
    )


def _with_dof_params(joint: Joint, m: mujoco.MjModel, jids: list[int]) -> Joint:
    low, high, kp, kd, arm, tau = [], [], [], [], [], []
    for j in jids:
        ndof = 3 if m.jnt_type[j] == _BALL else 1
        dofs = range(m.jnt_dofadr[j], m.jnt_dofadr[j] + ndof)
        if m.jnt_type[j] == _BALL:
            r = float(m.jnt_range[j][1]) if m.jnt_limited[j] else math.pi
            lo, hi = [-r] * 3, [r] * 3
        elif m.jnt_limited[j]:
            lo, hi = [float(m.jnt_range[j][0])], [float(m.jnt_range[j][1])]
        else:
            lo, hi = [-math.pi], [math.pi]
        low += lo
        high += hi
        kp += [float(m.jnt_stiffness[j])] * ndof
        kd += [float(m.dof_damping[d]) for d in dofs]
        arm += [float(m.dof_armature[d]) for d in dofs]
        tau += [_torque_limit(m, j)] * ndof
    joint.low, joint.high = np.array(low), np.array(high)
    joint.kp, joint.kd, joint.armature, joint.torque_limit = np.array(kp), np.array(kd), np.array(arm), np.array(tau)
    return joint


def _torque_limit(m: mujoco.MjModel, j: int) -> float:
    if m.jnt_actfrclimited[j]:
        return float(np.max(np.abs(m.jnt_actfrcrange[j])))
    for a in range(m.nu):
        if m.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT and m.actuator_trnid[a][0] == j:
            ctrl = np.max(np.abs(m.actuator_ctrlrange[a])) if m.actuator_ctrllimited[a] else 1.0
            return float(abs(m.actuator_gear[a][0]) * ctrl)
    return math.inf
