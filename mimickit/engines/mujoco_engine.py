"""The MuJoCo (CPU) engine: one compiled MjModel shared by all envs, one MjData per env.

Build: every object's MJCF is loaded with MjSpec, adapted (3-hinge bodies → one ball joint, passive
stiffness/damping zeroed, its own motors dropped, a free root joint or a mocap root for `fix_root`) and
attached under its own name prefix to a scene with a floor. The scene gets one actuator per DoF whose
gains follow the control mode, four state sensors per body (frame position and orientation, COM linear
and angular velocity, world frame) and two contact sensors per body (all contacts, floor contacts): MuJoCo
sums `mj_contactForce` per body in C, in the world frame, instead of a Python loop over contacts.

Step: worker threads (one per core) each step a contiguous chunk of envs with `mj_step(m, d, n)`, which
releases the GIL: first `substeps - 1` steps with sensors disabled, then the last one with them, then
`mj_kinematics / mj_comPos / mj_comVel / mj_sensorPos / mj_sensorVel` so that body poses and velocities
belong to the final qpos/qvel (mj_step leaves them one substep behind). Measured against
`mujoco.rollout` (bench_util): at equal states the pool runs at 0.95-1.0x rollout's speed, and it keeps
a live MjData per env for contacts and for drawing, which rollout's scratch data would not.

State: after a step, qpos, qvel and sensordata (body states and contact forces) of all envs are gathered
into stacked numpy arrays [N, ...] with one `np.concatenate` per field (three fields rather than eight:
1-3% of an env step at 256 envs, measured), converted with vectorised numpy, and written into float32
buffers that back the torch tensors the getters return (views: they stay live). Setters edit the stacked
qpos/qvel rows and mark the envs dirty; the next getter or step pushes them into the MjData and
recomputes the kinematics of those envs only (contact forces keep their last-step values until a step).

Frames (the engine contract in docs/architecture.md): MuJoCo's free joint velocity is (origin linear
velocity in world frame, angular velocity in body frame); the framework uses (centre-of-mass linear
velocity, angular velocity), both world frame. Ball-joint qpos quaternions (w first) are exposed as
exp-maps; ball qvel is already the local angular velocity.

Ball-joint limits (`ball_joint_limits`): "cone" limits each ball joint's rotation angle to the largest
|bound| of its hinges' ranges (MuJoCo's ball limit, the same one the Newton engine sets), "none" leaves
it unlimited; the per-axis ranges bound the actions either way (`get_obj_dof_limits`).

pd_explicit: τ = kp (q* − q) − kd q̇ per actuator, recomputed before every substep between `mj_step1`
(which computes the actuator lengths and velocities of the current state) and `mj_step2`. An actuator's
length is the hinge angle or, for a ball joint with gear e_i, exp-map component i; its velocity is q̇ or
the local angular velocity ω_i: the law the pos-mode actuators apply, with the damping explicit.
"""

from __future__ import annotations

import math
import os
import queue
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING

import mujoco
import numpy as np
import torch

from mimickit.anim.kin_char_model import JointType, KinCharModel
from mimickit.anim.mjcf_loader import compile_spec, load_mjcf_spec
from mimickit.engines.engine import (
    ControlMode,
    Engine,
    EngineConfig,
    EnvIds,
    MujocoView,
    ViewObject,
    ball_cone_angle,
    has_motors,
    mode_gains,
)
from mimickit.engines.engine_records import ObjLayout, ObjRecord, ObjState, state_shapes
from mimickit.util import torch_util as tu

if TYPE_CHECKING:
    from mimickit.engines.bench_util import RawRollout

FLOOR_NAME = "floor"

_INTEGRATORS = {
    "euler": mujoco.mjtIntegrator.mjINT_EULER,
    "rk4": mujoco.mjtIntegrator.mjINT_RK4,
    "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
    "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
}

# Contact sensor parameters (intprm): report the force only, summed over matching contacts into one
# world-frame "net force" (reduce mode 3 = netforce), one slot.
_CONTACT_SENSOR_INTPRM = [1 << int(mujoco.mjtConDataField.mjCONDATA_FORCE), 3, 1]

# MjData fields gathered into stacked [N, ...] arrays after every step: the body states are sensors.
# (Actuator forces are read only when asked for: the envs never do.)
_GATHERED_FIELDS = ("qpos", "qvel", "sensordata")

# Per body, the sensors whose readings are its state row (name suffix, type, frame; 13 values): the body
# frame's position and orientation (w first), the centre of mass's linear velocity (mjOBJ_BODY is the
# inertial frame) and the angular velocity, both in the world frame.
_BODY_SENSORS = (
    ("pos", mujoco.mjtSensor.mjSENS_FRAMEPOS, mujoco.mjtObj.mjOBJ_XBODY),
    ("quat", mujoco.mjtSensor.mjSENS_FRAMEQUAT, mujoco.mjtObj.mjOBJ_XBODY),
    ("linvel", mujoco.mjtSensor.mjSENS_FRAMELINVEL, mujoco.mjtObj.mjOBJ_BODY),
    ("angvel", mujoco.mjtSensor.mjSENS_FRAMEANGVEL, mujoco.mjtObj.mjOBJ_BODY),
)
_WXYZ_TO_XYZW_COLUMNS = [0, 1, 2, 4, 5, 6, 3, 7, 8, 9, 10, 11, 12]  # a body's 13 readings, quaternion w last

GUIDED_SPLIT = 2
"""Each chunk of the step queue takes 1/(GUIDED_SPLIT × threads) of the envs still unassigned (at least
one): big chunks first, single envs last, so the threads finish within about one env's step of each
other (fixed chunks of 16 envs left one core idle ~2 ms per control step at 256 envs, measured)."""


# ---------------------------------------------------------------------------------------------- records
@dataclass(kw_only=True)
class _ObjLayout(ObjLayout):
    """Where an object lives in the compiled model. Index arrays address qpos/qvel/body/sensor columns."""

    prefix: str
    body_ids: np.ndarray  # [B] MuJoCo body ids in kinematic DFS order
    root_qpos: int  # qpos address of the free root joint, -1 for a mocap (fixed) root
    root_qvel: int
    mocap_id: int  # -1 for a free root
    root_ipos: np.ndarray  # [3] centre of mass of the root body in its own frame
    dof_qvel: np.ndarray  # [D] qvel index of every DoF
    hinge_cols: np.ndarray  # [H] DoF columns of hinge joints
    hinge_qpos: np.ndarray  # [H] their qpos addresses
    ball_cols: np.ndarray  # [K, 3] DoF columns of ball joints (exp-map components)
    ball_qpos: np.ndarray  # [K, 4] their quaternion qpos addresses (w first)
    hinge_joints: np.ndarray  # [H] joint index (0 .. J-2, root excluded) of each hinge
    hinge_axes: np.ndarray  # [H, 3] unit hinge axes in the joint frame
    ball_joints: np.ndarray  # [K] joint index of each ball joint
    act_ids: np.ndarray  # [D] actuator per DoF, empty without motors
    body_adr: np.ndarray  # [B, 13] sensordata columns: position, rotation (x y z w), COM velocity, angular velocity
    contact_adr: np.ndarray  # [B * 3] sensordata columns: total contact force per body (on the sensor's body1)
    ground_adr: np.ndarray  # [B * 3] sensordata columns: floor contact force per body


class _ObjState(ObjState):
    """One object's state buffers. The refresh writes float32 numpy arrays `host[name]` (`state_shapes`,
    joint_rot included); the getters return the torch tensors `tensors[name]`, which share memory with
    `host` on the CPU and are uploaded copies on another device."""

    def __init__(self, n: int, b: int, d: int, device: torch.device):
        self.host = {k: np.zeros(s, dtype=np.float32) for k, s in state_shapes(n, b, d, joint_rot=True).items()}
        self.on_cpu = device.type == "cpu"
        super().__init__({
            k: torch.from_numpy(a) if self.on_cpu else torch.zeros(a.shape, device=device) for k, a in self.host.items()
        })  # fmt: skip

    def upload(self, rows: slice | np.ndarray, names: tuple[str, ...] | None = None) -> None:
        """Copy refreshed host rows to the device tensors (nothing to do on the CPU)."""
        if self.on_cpu:
            return
        for k in names or tuple(self.host):
            a, t = self.host[k], self.tensors[k]
            if isinstance(rows, slice):
                t[rows].copy_(torch.from_numpy(a[rows]))
            else:
                t[torch.from_numpy(rows).to(t.device)] = torch.from_numpy(a[rows]).to(t.device)


# ---------------------------------------------------------------------------------------------- scene build
def _zero_like(value: object) -> object:
    """0 in the shape MuJoCo uses for this attribute (scalar in older versions, array in 4.x)."""
    return np.zeros_like(value) if isinstance(value, np.ndarray) else 0.0


def _adapt_object_spec(
    spec: mujoco.MjSpec, rec: ObjRecord, kin: KinCharModel, limit_balls: bool
) -> dict[str, list[float]]:
    """Make an asset's spec simulation-ready in place; returns per-axis armature of each new ball joint.
    With `limit_balls` every ball joint gets its cone limit (`ball_cone_angle`), else none."""
    for elements in (spec.actuators, spec.sensors, spec.keys):  # own motors go; keyframes no longer fit
        for e in list(elements):
            spec.delete(e)
    for geom in list(spec.worldbody.geoms):  # the asset's own floor, if any: the scene has one
        spec.delete(geom)
    root = spec.worldbody.first_body()
    for j in list(root.joints):
        spec.delete(j)
    # The root pose is state (start_pos / start_rot per env), not part of the shared model.
    root.pos = [0.0, 0.0, 0.0]
    root.quat = [1.0, 0.0, 0.0, 0.0]
    if rec.fix_root:
        root.mocap = True  # welded to the world, yet movable per env through MjData.mocap_pos/quat
    else:
        root.add_freejoint()

    ball_armature: dict[str, list[float]] = {}
    for joint in kin.joints[1:]:
        body = spec.body(kin.body_names[joint.body_id])
        if joint.type == JointType.SPHERICAL:
            if len(body.joints) == 3:
                ball_armature[joint.name] = [float(spec.joint(n).armature) for n in joint.mjcf_joints]
                _hinges_to_ball(spec, body, joint.name, ball_armature[joint.name])
            cone = ball_cone_angle(joint.low, joint.high) if limit_balls else None
            _set_ball_limit(body.joints[0], cone, spec.compiler.degree)
        for j in body.joints:  # the gains move into actuators: no passive springs left
            j.stiffness = _zero_like(j.stiffness)
            j.damping = _zero_like(j.damping)

    for body in spec.bodies[1:]:
        if rec.is_visual:
            body.gravcomp = 1.0  # a ghost floats where the env puts it instead of falling between resets
        for geom in body.geoms:
            if rec.is_visual:
                geom.contype, geom.conaffinity = 0, 0
            if rec.color is not None:
                geom.rgba = list(rec.color[:3]) + [rec.color[3] if len(rec.color) > 3 else 1.0]
    return ball_armature


def _hinges_to_ball(spec: mujoco.MjSpec, body: mujoco.MjsBody, name: str, armature: list[float]) -> None:
    """Replace a body's x/y/z hinge triplet by one ball joint (as Newton's MJCF import does); its limit is
    set by `_set_ball_limit`."""
    hinges = list(body.joints)
    # Limit softness from the z hinge: Newton's MuJoCo conversion maps a ball joint to its last DoF.
    z = hinges[-1]
    solref, solimp, margin = list(z.solref_limit), list(z.solimp_limit), float(z.margin)
    for j in hinges:
        spec.delete(j)
    ball = body.add_joint(name=name, type=mujoco.mjtJoint.mjJNT_BALL)
    ball.solref_limit, ball.solimp_limit, ball.margin = solref, solimp, margin
    ball.actfrclimited = mujoco.mjtLimited.mjLIMITED_FALSE
    ball.armature = float(np.mean(armature))  # exact per-axis values are patched into the compiled model


def _set_ball_limit(ball: mujoco.MjsJoint, cone: float | None, degree: bool) -> None:
    """Limit a ball joint's rotation angle to `cone` (rad; MuJoCo's ball limit is this cone, range[1] with
    range[0] = 0), or leave it unlimited for None. `degree`: the MjSpec compiles angles in degrees (MuJoCo's
    default when the MJCF does not say angle="radian", e.g. SMPL)."""
    if cone is None:
        ball.limited = mujoco.mjtLimited.mjLIMITED_FALSE
        return
    ball.limited = mujoco.mjtLimited.mjLIMITED_TRUE
    ball.range = [0.0, math.degrees(cone) if degree else cone]


def _add_floor(scene: mujoco.MjSpec) -> None:
    scene.worldbody.add_geom(
        name=FLOOR_NAME,
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[0.0, 0.0, 0.05],
        condim=3,
        friction=[1.0, 0.005, 0.0001],
        rgba=[0.22, 0.24, 0.27, 1.0],
    )


def _set_options(scene: mujoco.MjSpec, config: EngineConfig) -> None:
    opt = scene.option
    opt.timestep = 1.0 / config.sim_freq
    opt.integrator = _INTEGRATORS[config.integrator]
    opt.cone = mujoco.mjtCone.mjCONE_PYRAMIDAL
    opt.solver = mujoco.mjtSolver.mjSOL_NEWTON
    opt.iterations = config.solver_iterations
    opt.ls_iterations = config.ls_iterations
    opt.impratio = 10.0  # mirrors Newton's SolverMuJoCo; only matters for elliptic cones


def _actuator_gains(mode: ControlMode, kp: float, kd: float) -> tuple[float, list[float]]:
    """(gain, bias[0:3]) of an affine actuator: force = gain·ctrl + b0 + b1·length + b2·velocity."""
    if mode == ControlMode.pos:
        return kp, [0.0, -kp, -kd]
    if mode == ControlMode.vel:
        return kd, [0.0, 0.0, -kd]
    return 1.0, [0.0, 0.0, 0.0]  # torque, and pd_explicit (its PD torque is computed by the engine)


def _add_dof_actuators(scene: mujoco.MjSpec, prefix: str, kin: KinCharModel, mode: ControlMode) -> None:
    """One actuator per DoF in DoF order; a ball joint gets three with gear e_x, e_y, e_z, whose length is
    the matching exp-map component of the joint rotation (MuJoCo's ball transmission)."""
    kp, kd, limit = kin.dof_array("kp"), kin.dof_array("kd"), kin.dof_array("torque_limit")
    for joint in kin.joints[1:]:
        for axis in range(joint.dof_dim):
            col = joint.dof_idx + axis
            act = scene.add_actuator()
            act.name = f"{prefix}{joint.name}_{'xyz'[axis]}" if joint.dof_dim == 3 else f"{prefix}{joint.name}"
            act.trntype = mujoco.mjtTrn.mjTRN_JOINT
            act.target = prefix + joint.name if joint.type == JointType.SPHERICAL else prefix + joint.mjcf_joints[0]
            gear = np.zeros(6)
            gear[axis] = 1.0
            act.gear = gear
            gain, bias = _actuator_gains(mode, float(kp[col]), float(kd[col]))
            gainprm, biasprm = np.zeros_like(act.gainprm), np.zeros_like(act.biasprm)
            gainprm[0], biasprm[:3] = gain, bias
            act.gaintype = mujoco.mjtGain.mjGAIN_FIXED
            act.biastype = mujoco.mjtBias.mjBIAS_AFFINE
            act.gainprm, act.biasprm = gainprm, biasprm
            act.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
            if np.isfinite(limit[col]):
                act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
                act.forcerange = [-float(limit[col]), float(limit[col])]


def _add_body_sensors(scene: mujoco.MjSpec, prefix: str, kin: KinCharModel) -> None:
    """Per body, the state sensors of `_BODY_SENSORS`: computed in C with the kinematics, so that a step's
    body states reach the stacked arrays in one copy per env (sensordata) rather than one per MjData field."""
    for name in kin.body_names:
        for suffix, sensor, objtype in _BODY_SENSORS:
            scene.add_sensor(name=f"{prefix}{name}_{suffix}", type=sensor, objtype=objtype, objname=prefix + name)


def _add_contact_sensors(scene: mujoco.MjSpec, prefix: str, kin: KinCharModel) -> None:
    """Per body: net force over all its contacts, then over its contacts with the floor."""
    for name in kin.body_names:
        for refname in (None, FLOOR_NAME):
            scene.add_sensor(
                name=f"{prefix}{name}_{'ground' if refname else 'contact'}",
                type=mujoco.mjtSensor.mjSENS_CONTACT,
                objtype=mujoco.mjtObj.mjOBJ_BODY,
                objname=prefix + name,
                reftype=mujoco.mjtObj.mjOBJ_GEOM if refname else mujoco.mjtObj.mjOBJ_UNKNOWN,
                refname=refname or "",
                intprm=_CONTACT_SENSOR_INTPRM,
            )


def _exclude_self_collisions(scene: mujoco.MjSpec, prefix: str, kin: KinCharModel) -> None:
    names = kin.body_names
    for a in range(len(names)):
        for b in range(a + 1, len(names)):
            scene.add_exclude(bodyname1=prefix + names[a], bodyname2=prefix + names[b])


# ---------------------------------------------------------------------------------------------- engine
class MujocoEngine(Engine):
    """MuJoCo on the CPU; see the module docstring. Tensor shapes as in `Engine`."""

    def __init__(self, config: EngineConfig, num_envs: int, device: torch.device | str, visualize: bool = False):
        super().__init__(config, num_envs, device, visualize)
        self.mj_model: mujoco.MjModel | None = None
        self.mj_datas: list[mujoco.MjData] = []
        self._pool: ThreadPoolExecutor | None = None
        self._chunks: list[slice] = []  # env rows per worker thread, set by initialize_sim
        self._view_objects: tuple[ViewObject, ...] | None = None  # mujoco_view's, built on its first call

    def get_name(self) -> str:
        return "mujoco"

    # ------------------------------------------------------------------ creation
    def _sim_initialized(self) -> bool:
        return self.mj_model is not None

    def initialize_sim(self) -> None:
        objs = self._check_env_objects()
        self.mj_model, self._layouts = self._build_model(objs)
        m = self.mj_model
        self.mj_datas = [mujoco.MjData(m) for _ in range(self._num_envs)]
        self._views = {f: [getattr(d, f) for d in self.mj_datas] for f in _GATHERED_FIELDS}
        self._host = {f: np.zeros((self._num_envs, *self._views[f][0].shape)) for f in _GATHERED_FIELDS}
        self._mocap_pos = np.zeros((self._num_envs, m.nmocap, 3))
        self._mocap_quat = np.zeros((self._num_envs, m.nmocap, 4))
        self._ctrl = np.zeros((self._num_envs, m.nu))
        self._pd_target = np.zeros((self._num_envs, m.nu))
        self._act_kp, self._act_kd = self._actuator_gains()
        self._dirty = np.zeros(self._num_envs, dtype=bool)
        self._states = [_ObjState(self._num_envs, lay.num_bodies, lay.num_dofs, self._device) for lay in self._layouts]
        self._place_start_poses()
        self._init_threads()
        self._sync(force_all=True)
        for d in self.mj_datas:  # contacts and sensors of the start state, so that getters start sensible
            mujoco.mj_forward(m, d)
        self._gather(slice(None))
        self._refresh(slice(None))
        if self._config.control_mode == ControlMode.pd_explicit:
            self._check_explicit_damping()

    def _check_explicit_damping(self) -> None:
        """Warn when pd_explicit's damping is too stiff for the timestep (mass matrix of env 0's start state)."""
        m, d = self.mj_model, self.mj_datas[0]
        full = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, full)
        for lay in self._layouts:
            if len(lay.act_ids):
                self._warn_explicit_damping(lay.kin, lay.kd, np.diag(full)[lay.dof_qvel])

    def _actuator_gains(self) -> tuple[np.ndarray, np.ndarray]:
        """(kp, kd) [nu] per actuator of the scene, as the control mode uses them (pd_explicit's gains)."""
        kp, kd = np.zeros(self.mj_model.nu), np.zeros(self.mj_model.nu)
        for lay in self._layouts:
            if len(lay.act_ids):  # objects without motors have no actuators
                kp[lay.act_ids], kd[lay.act_ids] = lay.kp, lay.kd
        return kp, kd

    def _build_model(self, objs: list[ObjRecord]) -> tuple[mujoco.MjModel, list[_ObjLayout]]:
        cfg = self._config
        scene = mujoco.MjSpec()
        scene.modelname = "mimickit_scene"
        _set_options(scene, cfg)
        _add_floor(scene)
        prefixes, ball_armature = [], []
        for i, rec in enumerate(objs):
            kin = self._kin_model(rec.asset_file)
            spec = load_mjcf_spec(rec.asset_file)
            ball_armature.append(_adapt_object_spec(spec, rec, kin, cfg.ball_joint_limits == "cone"))
            prefix = f"{i}_{rec.name}/"
            scene.attach(spec, prefix=prefix, frame=scene.worldbody.add_frame())
            if not rec.enable_self_collisions:
                _exclude_self_collisions(scene, prefix, kin)
            if has_motors(self._config.control_mode, rec, kin):
                _add_dof_actuators(scene, prefix, kin, cfg.control_mode)
            _add_body_sensors(scene, prefix, kin)
            if not rec.is_visual:
                _add_contact_sensors(scene, prefix, kin)
            prefixes.append(prefix)
        m = compile_spec(scene, objs[0].asset_file if objs else "scene")
        layouts = [self._layout(m, rec, prefix) for rec, prefix in zip(objs, prefixes, strict=True)]
        for lay, armature in zip(layouts, ball_armature, strict=True):
            for jname, values in armature.items():  # per-axis hinge armature onto the ball's 3 DoFs
                j = m.joint(lay.prefix + jname).id
                m.dof_armature[m.jnt_dofadr[j] : m.jnt_dofadr[j] + 3] = values
        return m, layouts

    def _layout(self, m: mujoco.MjModel, rec: ObjRecord, prefix: str) -> _ObjLayout:
        kin = self._kin_model(rec.asset_file)
        body_ids = np.array([m.body(prefix + n).id for n in kin.body_names])
        root = int(body_ids[0])
        free = m.body_jntnum[root] == 1
        root_jnt = int(m.body_jntadr[root])
        dof_qvel, hinge_cols, hinge_qpos, ball_cols, ball_qpos = [], [], [], [], []
        hinge_joints, hinge_axes, ball_joints = [], [], []
        for jid, joint in enumerate(kin.joints[1:]):
            if joint.dof_dim == 0:
                continue
            j = int(m.body_jntadr[body_ids[joint.body_id]])
            qadr, vadr = int(m.jnt_qposadr[j]), int(m.jnt_dofadr[j])
            if joint.type == JointType.HINGE:
                hinge_cols.append(joint.dof_idx)
                hinge_qpos.append(qadr)
                dof_qvel.append(vadr)
                hinge_joints.append(jid)
                hinge_axes.append(np.asarray(joint.axis, dtype=np.float64) / np.linalg.norm(joint.axis))
            else:
                ball_cols.append([joint.dof_idx + k for k in range(3)])
                ball_qpos.append([qadr + k for k in range(4)])
                dof_qvel += [vadr + k for k in range(3)]
                ball_joints.append(jid)
        act_names = self._actuator_names(kin) if has_motors(self._config.control_mode, rec, kin) else []
        act_ids = np.array([m.actuator(prefix + a).id for a in act_names], dtype=np.int64)
        body_adr = [
            [col for suffix, _, _ in _BODY_SENSORS for col in _sensor_columns(m, f"{prefix}{n}_{suffix}")]
            for n in kin.body_names
        ]
        contact_adr, ground_adr = [], []
        if not rec.is_visual:
            for n in kin.body_names:
                contact_adr += _sensor_columns(m, f"{prefix}{n}_contact")
                ground_adr += _sensor_columns(m, f"{prefix}{n}_ground")
        lay = _ObjLayout(
            kin=kin,
            actuated=has_motors(self._config.control_mode, rec, kin),
            prefix=prefix,
            body_ids=body_ids,
            root_qpos=int(m.jnt_qposadr[root_jnt]) if free else -1,
            root_qvel=int(m.jnt_dofadr[root_jnt]) if free else -1,
            mocap_id=-1 if free else int(m.body_mocapid[root]),
            root_ipos=m.body_ipos[root].copy(),
            dof_qvel=np.array(dof_qvel, dtype=np.int64),
            hinge_cols=np.array(hinge_cols, dtype=np.int64),
            hinge_qpos=np.array(hinge_qpos, dtype=np.int64),
            ball_cols=np.array(ball_cols, dtype=np.int64).reshape(-1, 3),
            ball_qpos=np.array(ball_qpos, dtype=np.int64).reshape(-1, 4),
            hinge_joints=np.array(hinge_joints, dtype=np.int64),
            hinge_axes=np.array(hinge_axes, dtype=np.float64).reshape(-1, 3),
            ball_joints=np.array(ball_joints, dtype=np.int64),
            act_ids=act_ids.astype(np.int64),
            body_adr=np.array(body_adr, dtype=np.int64)[:, _WXYZ_TO_XYZW_COLUMNS],
            contact_adr=np.array(contact_adr, dtype=np.int64),
            ground_adr=np.array(ground_adr, dtype=np.int64),
        )
        lay.kp, lay.kd = mode_gains(self._config.control_mode, kin, lay.actuated)
        return lay

    @staticmethod
    def _actuator_names(kin: KinCharModel) -> list[str]:
        return [f"{j.name}_{'xyz'[a]}" if j.dof_dim == 3 else j.name for j in kin.joints[1:] for a in range(j.dof_dim)]

    def _place_start_poses(self) -> None:
        """Write every env's start poses into the stacked state (pushed into MjData by `_sync`)."""
        qpos0 = self.mj_model.qpos0
        self._host["qpos"][:] = qpos0
        for e, poses in enumerate(self._start_poses):
            for lay, (pos, rot) in zip(self._layouts, poses, strict=True):
                wxyz = np.array([rot[3], rot[0], rot[1], rot[2]])
                if lay.root_qpos >= 0:
                    self._host["qpos"][e, lay.root_qpos : lay.root_qpos + 3] = pos
                    self._host["qpos"][e, lay.root_qpos + 3 : lay.root_qpos + 7] = wxyz
                else:
                    self._mocap_pos[e, lay.mocap_id] = pos
                    self._mocap_quat[e, lay.mocap_id] = wxyz

    def _init_threads(self) -> None:
        nthread = self._config.num_threads or os.cpu_count() or 1
        self._nthread = max(1, min(nthread, self._num_envs))
        self._chunks = _guided_chunks(self._num_envs, self._nthread)
        # Per env: (MjData, its ctrl array, the env's row of the command buffer), iterated by the workers.
        self._env_io = [(d, d.ctrl, self._ctrl[i]) for i, d in enumerate(self.mj_datas)]
        self._pool = ThreadPoolExecutor(max_workers=self._nthread - 1) if self._nthread > 1 else None

    @property
    def num_threads(self) -> int:
        """Threads that step the envs (the calling thread included)."""
        return self._nthread if self._pool is not None else 1

    def close(self) -> None:
        """Stop the worker threads; later steps run on the calling thread alone."""
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    # ------------------------------------------------------------------ stepping
    def set_cmd(self, obj_id: int, cmd: torch.Tensor) -> None:
        lay = self._layouts[obj_id]
        mode = self._config.control_mode
        if mode == ControlMode.none or len(lay.act_ids) == 0:
            return
        values = np.broadcast_to(_to_numpy(cmd), (self._num_envs, lay.num_dofs))
        target = self._pd_target if mode == ControlMode.pd_explicit else self._ctrl
        target[:, lay.act_ids] = values

    def step(self, concurrent: Callable[[], None] | None = None) -> None:
        self._push_edits()
        nsub = self._config.substeps
        if nsub > 1:
            # The sensors (our contact-force readout, ~6% of a substep) are read only after the last
            # substep: switch them off before it. The flag is flipped only while no worker runs.
            opt = self.mj_model.opt
            flags = opt.disableflags
            opt.disableflags = flags | mujoco.mjtDisableBit.mjDSBL_SENSOR
            try:
                self._run_workers(nsub - 1, first=True, last=False, concurrent=concurrent)
            finally:
                opt.disableflags = flags
            concurrent = None
        self._run_workers(1, first=nsub == 1, last=True, concurrent=concurrent)
        # Gather and refresh once here rather than per chunk in the workers: measured as fast or faster
        # (numpy ops in a worker hold the GIL that the other workers need between mj_step calls).
        self._gather(slice(None))
        self._refresh(slice(None))
        self._sim_time += self.get_timestep()

    def _run_workers(self, nstep: int, first: bool, last: bool, concurrent: Callable[[], None] | None = None) -> None:
        """Advance every env `nstep` substeps. The threads take chunks from one queue (see GUIDED_SPLIT);
        with `concurrent`, the calling thread runs it first and then takes chunks too, so the envs it would
        have stepped go to whichever thread is free."""
        pd = self._config.control_mode == ControlMode.pd_explicit
        worker = partial(self._step_chunk_pd_explicit if pd else self._step_chunk, nstep=nstep, first=first, last=last)
        if self._pool is None:  # one thread, or closed
            if concurrent is not None:
                concurrent()
            worker(slice(None))
            return
        todo: queue.SimpleQueue[slice] = queue.SimpleQueue()
        for chunk in self._chunks:
            todo.put(chunk)

        def drain() -> None:
            while True:
                try:
                    chunk = todo.get_nowait()
                except queue.Empty:
                    return
                worker(chunk)

        futures = [self._pool.submit(drain) for _ in range(self._nthread - 1)]
        try:
            if concurrent is not None:
                concurrent()
        finally:
            drain()
            for f in futures:
                f.result()  # re-raises a worker's exception here

    def _step_chunk(self, rows: slice, nstep: int, first: bool, last: bool) -> None:
        """Worker: `nstep` substeps of a contiguous chunk of envs (mj_step releases the GIL, so chunks run
        in parallel); the command is applied on the first call of a control step, kinematics after the last."""
        m = self.mj_model
        for d, ctrl, cmd in self._env_io[rows]:
            if first:
                ctrl[:] = cmd
            mujoco.mj_step(m, d, nstep)
            if last:
                _update_kinematics(m, d)

    def _step_chunk_pd_explicit(self, rows: slice, nstep: int, first: bool, last: bool) -> None:
        """Worker for pd_explicit: τ = kp (q* − q) − kd q̇ per actuator before every substep, from the actuator
        lengths q and velocities q̇ that `mj_step1` computes for the current state (for a ball joint: exp-map
        component and local angular velocity). The actuators' forcerange clips τ to ± the torque limit."""
        m, kp, kd = self.mj_model, self._act_kp, self._act_kd
        # mj_step2 integrates with Euler for RK4: there the full mj_step recomputes the forward pass.
        finish = mujoco.mj_step if m.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4 else mujoco.mj_step2
        for (d, ctrl, _), target in zip(self._env_io[rows], self._pd_target[rows], strict=True):
            for _ in range(nstep):
                mujoco.mj_step1(m, d)
                np.multiply(kp, target - d.actuator_length, out=ctrl)
                ctrl -= kd * d.actuator_velocity
                finish(m, d)
            if last:
                _update_kinematics(m, d)

    # ------------------------------------------------------------------ state sync
    def _gather(self, rows: slice | np.ndarray) -> None:
        """Copy MjData fields of env rows `rows` into the stacked host arrays; a contiguous slice costs one
        C-level `np.concatenate` per field instead of a Python loop over envs."""
        for f in _GATHERED_FIELDS:
            views, out = self._views[f], self._host[f]
            if isinstance(rows, slice):
                block = out[rows]
                np.concatenate(views[rows], axis=0, out=block.reshape(-1, *out.shape[2:]))
            else:
                for i in rows:
                    out[i] = views[i]

    def _sync(self, force_all: bool = False) -> None:
        """Push setter edits of dirty envs into their MjData and recompute their kinematics and state rows
        (what a getter needs)."""
        if force_all:
            self._dirty[:] = True
        ids = self._push_edits()
        if len(ids) == 0:
            return
        for i in ids:
            _update_kinematics(self.mj_model, self.mj_datas[i])
        self._gather(ids)
        self._refresh(ids, contacts=False)

    def _push_edits(self) -> np.ndarray:
        """Write setter edits of dirty envs into their MjData; returns their ids. Enough before a step:
        `mj_step` recomputes all that depends on qpos/qvel, and the step's refresh covers every env, so
        edits no getter read (a reset whose observations come from the state it set) cost no kinematics."""
        if not self._dirty.any():
            return np.empty(0, dtype=int)
        ids = np.flatnonzero(self._dirty)
        m = self.mj_model
        qpos, qvel = self._host["qpos"], self._host["qvel"]
        qpos_views, qvel_views = self._views["qpos"], self._views["qvel"]
        for i in ids:
            qpos_views[i][:] = qpos[i]
            qvel_views[i][:] = qvel[i]
            if m.nmocap:
                d = self.mj_datas[i]
                d.mocap_pos[:] = self._mocap_pos[i]
                d.mocap_quat[:] = self._mocap_quat[i]
        self._dirty[:] = False
        return ids

    def _refresh(self, rows: slice | np.ndarray, contacts: bool = True) -> None:
        """Recompute every object's state rows (a slice or env indices) from the stacked host arrays.

        Plain numpy on purpose: torch ops on [N, ...] tensors wake torch's OpenMP workers, which then
        spin on the cores the MuJoCo worker threads need for the next step (measured: -35% at 64 envs)."""
        h = {f: a[rows] for f, a in self._host.items()}  # views for a slice, copies for indices
        for lay, st in zip(self._layouts, self._states, strict=True):
            _refresh_obj(lay, st.host, h, rows, contacts)
            st.upload(rows)

    # ------------------------------------------------------------------ getters
    def _state(self, obj_id: int) -> _ObjState:
        self._sync()
        return self._states[obj_id]

    def _state_tensor(self, obj_id: int, name: str) -> torch.Tensor:
        return self._state(obj_id).tensors[name]

    def get_joint_rot(self, obj_id: int) -> torch.Tensor:
        return self._state(obj_id).tensors["joint_rot"]

    def get_dof_forces(self, obj_id: int) -> torch.Tensor:
        """[N, D] actuator forces of the last substep, read from MjData at this call (not a live view)."""
        st, lay = self._state(obj_id), self._layouts[obj_id]
        if len(lay.act_ids):
            st.host["dof_forces"][:] = np.stack([d.actuator_force[lay.act_ids] for d in self.mj_datas])
            st.upload(slice(None), ("dof_forces",))
        return st.tensors["dof_forces"]

    # ------------------------------------------------------------------ setters
    def set_root_pos(self, env_ids: EnvIds, obj_id: int, root_pos: torch.Tensor | float) -> None:
        ids, lay = self._env_ids(env_ids), self._layouts[obj_id]
        pos = _rows(root_pos, len(ids), 3)
        if lay.root_qpos >= 0:
            self._host["qpos"][ids, lay.root_qpos : lay.root_qpos + 3] = pos
        else:
            self._mocap_pos[ids, lay.mocap_id] = pos
        self._dirty[ids] = True

    def set_root_rot(self, env_ids: EnvIds, obj_id: int, root_rot: torch.Tensor | float) -> None:
        ids, lay = self._env_ids(env_ids), self._layouts[obj_id]
        rot = _rows(root_rot, len(ids), 4)
        wxyz = rot[:, [3, 0, 1, 2]] / np.linalg.norm(rot, axis=-1, keepdims=True)
        if lay.root_qpos >= 0:
            vel, ang_vel = self._root_vel_world(ids, lay)  # keep the world-frame velocities
            self._host["qpos"][ids, lay.root_qpos + 3 : lay.root_qpos + 7] = wxyz
            self._write_root_vel(ids, lay, vel, ang_vel)
        else:
            self._mocap_quat[ids, lay.mocap_id] = wxyz
        self._dirty[ids] = True

    def set_root_vel(self, env_ids: EnvIds, obj_id: int, root_vel: torch.Tensor | float) -> None:
        ids, lay = self._env_ids(env_ids), self._layouts[obj_id]
        if lay.root_qpos < 0:
            return  # a fixed root does not move
        _, ang_vel = self._root_vel_world(ids, lay)
        self._write_root_vel(ids, lay, _rows(root_vel, len(ids), 3), ang_vel)
        self._dirty[ids] = True

    def set_root_ang_vel(self, env_ids: EnvIds, obj_id: int, root_ang_vel: torch.Tensor | float) -> None:
        ids, lay = self._env_ids(env_ids), self._layouts[obj_id]
        if lay.root_qpos < 0:
            return
        vel, _ = self._root_vel_world(ids, lay)
        self._write_root_vel(ids, lay, vel, _rows(root_ang_vel, len(ids), 3))
        self._dirty[ids] = True

    def set_dof_pos(self, env_ids: EnvIds, obj_id: int, dof_pos: torch.Tensor | float) -> None:
        ids, lay = self._env_ids(env_ids), self._layouts[obj_id]
        dof = _rows(dof_pos, len(ids), lay.num_dofs)
        qpos = self._host["qpos"]
        if len(lay.hinge_cols):
            qpos[np.ix_(ids, lay.hinge_qpos)] = dof[:, lay.hinge_cols]
        if len(lay.ball_cols):
            quat = tu.quat_to_wxyz(tu.exp_map_to_quat(torch.from_numpy(dof[:, lay.ball_cols])))  # [n, K, 4]
            qpos[ids[:, None, None], lay.ball_qpos[None]] = quat.numpy()
        self._dirty[ids] = True

    def set_joint_rot(self, env_ids: EnvIds, obj_id: int, joint_rot: torch.Tensor) -> None:
        """Ball joints take the quaternions as they are (MuJoCo stores quaternions); hinges the angle of
        the rotation about their axis, as `rot_to_dof`."""
        ids, lay = self._env_ids(env_ids), self._layouts[obj_id]
        rot = np.broadcast_to(_to_numpy(joint_rot).astype(np.float64), (len(ids), lay.num_bodies - 1, 4))
        qpos = self._host["qpos"]
        if len(lay.hinge_cols):
            q = rot[:, lay.hinge_joints]
            q = np.where(q[..., 3:] < 0, -q, q)
            angle = 2.0 * np.arctan2((q[..., :3] * lay.hinge_axes).sum(-1), q[..., 3])
            qpos[np.ix_(ids, lay.hinge_qpos)] = angle
        if len(lay.ball_cols):
            q = rot[:, lay.ball_joints][..., [3, 0, 1, 2]]
            qpos[ids[:, None, None], lay.ball_qpos[None]] = q / np.linalg.norm(q, axis=-1, keepdims=True)
        self._dirty[ids] = True

    def set_dof_vel(self, env_ids: EnvIds, obj_id: int, dof_vel: torch.Tensor | float) -> None:
        ids, lay = self._env_ids(env_ids), self._layouts[obj_id]
        self._host["qvel"][np.ix_(ids, lay.dof_qvel)] = _rows(dof_vel, len(ids), lay.num_dofs)
        self._dirty[ids] = True

    def set_root_state(
        self,
        env_ids: EnvIds,
        obj_id: int,
        root_pos: torch.Tensor | float,
        root_rot: torch.Tensor | float,
        root_vel: torch.Tensor | float,
        root_ang_vel: torch.Tensor | float,
    ) -> None:
        """All four at once: the velocities are converted to free-joint qvel once, with the new rotation."""
        ids, lay = self._env_ids(env_ids), self._layouts[obj_id]
        if lay.root_qpos < 0:
            self.set_root_pos(ids, obj_id, root_pos)
            self.set_root_rot(ids, obj_id, root_rot)
            return
        n, qpos = len(ids), self._host["qpos"]
        rot = _rows(root_rot, n, 4)
        qpos[ids, lay.root_qpos : lay.root_qpos + 3] = _rows(root_pos, n, 3)
        qpos[ids, lay.root_qpos + 3 : lay.root_qpos + 7] = rot[:, [3, 0, 1, 2]] / np.linalg.norm(
            rot, axis=-1, keepdims=True
        )
        self._write_root_vel(ids, lay, _rows(root_vel, n, 3), _rows(root_ang_vel, n, 3))
        self._dirty[ids] = True

    def _root_rot_wxyz(self, ids: np.ndarray, lay: _ObjLayout) -> np.ndarray:
        q = self._host["qpos"][ids, lay.root_qpos + 3 : lay.root_qpos + 7]
        return q / np.linalg.norm(q, axis=-1, keepdims=True)

    def _root_vel_world(self, ids: np.ndarray, lay: _ObjLayout) -> tuple[np.ndarray, np.ndarray]:
        """Current root (COM velocity, angular velocity), world frame, [n, 3] each, from the stacked qvel."""
        rot = self._root_rot_wxyz(ids, lay)
        qv = self._host["qvel"][ids, lay.root_qvel : lay.root_qvel + 6]
        ang_vel = _rotate_wxyz(rot, qv[:, 3:])
        vel = qv[:, :3] + _cross(ang_vel, _rotate_wxyz(rot, lay.root_ipos))
        return vel, ang_vel

    def _write_root_vel(self, ids: np.ndarray, lay: _ObjLayout, vel: np.ndarray, ang_vel: np.ndarray) -> None:
        """Store world-frame (COM velocity, angular velocity) [n, 3] as MuJoCo free-joint qvel."""
        rot = self._root_rot_wxyz(ids, lay)
        qvel = self._host["qvel"]
        qvel[ids, lay.root_qvel : lay.root_qvel + 3] = vel - _cross(ang_vel, _rotate_wxyz(rot, lay.root_ipos))
        inv = rot * np.array([1.0, -1.0, -1.0, -1.0])
        qvel[ids, lay.root_qvel + 3 : lay.root_qvel + 6] = _rotate_wxyz(inv, ang_vel)

    def _env_ids(self, env_ids: EnvIds) -> np.ndarray:
        if env_ids is None:
            return np.arange(self._num_envs)
        return np.asarray(_to_numpy(env_ids), dtype=np.int64).reshape(-1)

    # ------------------------------------------------------------------ viewers and the bench
    def mujoco_view(self, env_id: int = 0) -> MujocoView:
        """The engine's own model and env `env_id`'s live MjData, with pending setter edits pushed (as any
        getter does): no copy, so drawing costs the simulation nothing."""
        i = self._check_view_env(env_id)
        self._sync()
        if self._view_objects is None:
            self._view_objects = tuple(
                ViewObject(rec.name, rec.is_visual, _read_only(lay.body_ids))
                for rec, lay in zip(self._env_objs[0], self._layouts, strict=True)
            )
        return MujocoView(self.mj_model, self.mj_datas[i], self._view_objects)

    def raw_rollout(self) -> RawRollout:
        """`mujoco.rollout` on the engine's threads over its model, from copies of the envs' current states."""
        from mimickit.engines.bench_util import RawRollout  # mujoco.rollout: only for the bench

        return RawRollout(self.mj_model, self.mj_datas, self.num_threads, self._config.substeps)

    # ------------------------------------------------------------------ replay (benchmarks)
    def physics_state(self) -> tuple[np.ndarray, np.ndarray]:
        """What each env's next step starts from, to replay it elsewhere (`mujoco.rollout`): full-physics
        states [N, nstate] (setter edits not yet pushed included) and solver warm starts [N, nv]."""
        m, spec = self.mj_model, mujoco.mjtState.mjSTATE_FULLPHYSICS
        state = np.empty((self._num_envs, mujoco.mj_stateSize(m, spec)))
        for i, d in enumerate(self.mj_datas):
            mujoco.mj_getState(m, d, state[i], spec)
        # The state vector starts with time, qpos, qvel (mjtState order); edits wait in the host arrays.
        state[:, 1 : 1 + m.nq] = self._host["qpos"]
        state[:, 1 + m.nq : 1 + m.nq + m.nv] = self._host["qvel"]
        warm = np.stack([d.qacc_warmstart for d in self.mj_datas])
        return state, warm

    def get_ctrl(self) -> np.ndarray:
        """The actuator controls [N, nu] the last `set_cmd` calls wrote (held over a step's substeps except in
        pd_explicit mode, which recomputes them every substep)."""
        return self._ctrl.copy()

    # ------------------------------------------------------------------ queries
    def get_gravity(self) -> np.ndarray:
        return self.mj_model.opt.gravity.copy()

    def calc_obj_mass(self, env_id: int, obj_id: int) -> float:
        return float(self.mj_model.body_mass[self._layouts[obj_id].body_ids].sum())


# ---------------------------------------------------------------------------------------------- helpers
def _guided_chunks(n: int, nthread: int) -> list[slice]:
    """Contiguous env slices covering 0..n, each 1/(GUIDED_SPLIT × nthread) of what is left (at least 1)."""
    chunks, lo = [], 0
    while lo < n:
        size = max(1, -(-(n - lo) // (GUIDED_SPLIT * nthread)))
        chunks.append(slice(lo, lo + size))
        lo += size
    return chunks


def _sensor_columns(m: mujoco.MjModel, name: str) -> list[int]:
    s = m.sensor(name)
    return list(range(int(s.adr[0]), int(s.adr[0]) + int(s.dim[0])))


def _update_kinematics(m: mujoco.MjModel, d: mujoco.MjData) -> None:
    """Body poses, COM frames and velocities, and the body state sensors, for the current qpos/qvel
    (contacts and the contact sensors, computed with the accelerations, are left as they are)."""
    mujoco.mj_kinematics(m, d)
    mujoco.mj_comPos(m, d)
    mujoco.mj_comVel(m, d)
    mujoco.mj_sensorPos(m, d)
    mujoco.mj_sensorVel(m, d)


def _refresh_obj(
    lay: _ObjLayout, out: dict[str, np.ndarray], h: dict[str, np.ndarray], rows: slice | np.ndarray, contacts: bool
) -> None:
    """Write one object's state rows `rows` of `out` (see `_ObjState`) from stacked MjData fields h[field]
    [n, ...] (float64, already restricted to those rows)."""
    body = h["sensordata"][:, lay.body_adr]  # [n, B, 13] (see _ObjLayout.body_adr)
    out["body_pos"][rows] = body[..., 0:3]
    out["body_rot"][rows] = body[..., 3:7]
    out["body_vel"][rows] = body[..., 7:10]
    out["body_ang_vel"][rows] = body[..., 10:13]

    if lay.num_dofs:
        qpos = h["qpos"]
        dof_pos = np.empty((qpos.shape[0], lay.num_dofs))
        dof_pos[:, lay.hinge_cols] = qpos[:, lay.hinge_qpos]
        ball = _quat_wxyz_canonical(qpos[:, lay.ball_qpos])
        dof_pos[:, lay.ball_cols] = _quat_wxyz_to_exp_map(ball)
        out["dof_pos"][rows] = dof_pos
        out["joint_rot"][rows] = _joint_rot(lay, qpos[:, lay.hinge_qpos], ball)
        out["dof_vel"][rows] = h["qvel"][:, lay.dof_qvel]

    if contacts and len(lay.contact_adr):
        n, nb = body.shape[0], lay.num_bodies
        # The sensors report the force their body exerts on the others: negate for the force on the body.
        out["contact_forces"][rows] = 0.0 - h["sensordata"][:, lay.contact_adr].reshape(n, nb, 3)
        out["ground_contact_forces"][rows] = 0.0 - h["sensordata"][:, lay.ground_adr].reshape(n, nb, 3)


def _quat_wxyz_canonical(q: np.ndarray) -> np.ndarray:
    """Quaternions [..., 4] (w first) normalised, with w >= 0."""
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def _joint_rot(lay: _ObjLayout, hinge_angle: np.ndarray, ball_wxyz: np.ndarray) -> np.ndarray:
    """Local joint rotations [n, J-1, 4] (xyzw) from hinge angles [n, H] and canonical ball quaternions
    [n, K, 4] (w first): what `KinCharModel.dof_to_rot` gives for the DoFs, without the exp-map trip."""
    n = hinge_angle.shape[0]
    rot = np.zeros((n, lay.num_bodies - 1, 4))
    rot[..., 3] = 1.0
    half = 0.5 * hinge_angle[..., None]
    rot[:, lay.hinge_joints, :3] = lay.hinge_axes * np.sin(half)
    rot[:, lay.hinge_joints, 3:] = np.cos(half)
    rot[:, lay.ball_joints] = ball_wxyz[..., [1, 2, 3, 0]]
    return rot


def _quat_wxyz_to_exp_map(q: np.ndarray) -> np.ndarray:
    """Canonical MuJoCo quaternions [..., 4] (w first, unit, w >= 0: `_quat_wxyz_canonical`) to exp-maps
    [..., 3]: numpy twin of `torch_util.quat_to_exp_map` (the angle is in [0, π], zero near identity)."""
    v = q[..., 1:]
    sin_half = np.linalg.norm(v, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(sin_half, q[..., :1])
    small = sin_half <= 1e-5
    return np.where(small, 0.0, v * (angle / np.where(small, 1.0, sin_half)))


def _rotate_wxyz(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate v [n, 3] (or one [3]) by unit quaternions q [n, 4] (w first)."""
    w, u = q[:, :1], q[:, 1:]
    t = 2.0 * _cross(u, v)
    return v + w * t + _cross(u, t)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b over the last axis, broadcasting; on these small arrays np.cross spends most of its time
    on argument handling (axis moves), several times the arithmetic."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _read_only(a: np.ndarray) -> np.ndarray:
    a = a.copy()
    a.setflags(write=False)
    return a


def _to_numpy(x: object) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        return x.detach().cpu().numpy()
    return np.asarray(x)


def _rows(value: torch.Tensor | float, n: int, width: int) -> np.ndarray:
    """Broadcast a setter value to a float64 [n, width] array."""
    return np.array(np.broadcast_to(_to_numpy(value).astype(np.float64), (n, width)))
