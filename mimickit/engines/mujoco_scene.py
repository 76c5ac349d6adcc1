"""Scene building of the MuJoCo engine: one `MjSpec` scene compiled into the `MjModel` all envs share.

Every object's MJCF is loaded with MjSpec, adapted (3-hinge bodies → one ball joint, passive
stiffness/damping zeroed, its own motors dropped, a free root joint or a mocap root for `fix_root`) and
attached under its own name prefix to a scene with a floor. The scene gets one actuator per DoF whose
gains follow the control mode, four state sensors per body (frame position and orientation, COM linear
and angular velocity, world frame) and two contact sensors per body (all contacts, floor contacts): MuJoCo
sums `mj_contactForce` per body in C, in the world frame, instead of a Python loop over contacts.

Ball-joint limits (`ball_joint_limits`): "cone" limits each ball joint's rotation angle to the largest
|bound| of its hinges' ranges (MuJoCo's ball limit, the same one the Newton engine sets), "none" leaves
it unlimited; the per-axis ranges bound the actions either way (`get_obj_dof_limits`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from mimickit.anim.kin_char_model import JointType, KinCharModel
from mimickit.anim.mjcf_loader import compile_spec, load_mjcf_spec
from mimickit.engines.engine import ControlMode, EngineConfig, ball_cone_angle, has_motors, mode_gains
from mimickit.engines.engine_records import ObjLayout, ObjRecord

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


@dataclass(kw_only=True)
class MjObjLayout(ObjLayout):
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


def build_scene(
    config: EngineConfig, objs: list[ObjRecord], kins: list[KinCharModel]
) -> tuple[mujoco.MjModel, list[MjObjLayout]]:
    """Compile one env's scene: a floor and every object (`kins`: their kinematic models) under the prefix
    `{i}_{name}/`, with the actuators and sensors of the module docstring; returns the model and where each
    object lives in it."""
    scene = mujoco.MjSpec()
    scene.modelname = "mimickit_scene"
    _set_options(scene, config)
    _add_floor(scene)
    prefixes, ball_armature = [], []
    for i, rec in enumerate(objs):
        kin = kins[i]
        spec = load_mjcf_spec(rec.asset_file)
        ball_armature.append(_adapt_object_spec(spec, rec, kin, config.ball_joint_limits == "cone"))
        prefix = f"{i}_{rec.name}/"
        scene.attach(spec, prefix=prefix, frame=scene.worldbody.add_frame())
        if not rec.enable_self_collisions:
            _exclude_self_collisions(scene, prefix, kin)
        if has_motors(config.control_mode, rec, kin):
            _add_dof_actuators(scene, prefix, kin, config.control_mode)
        _add_body_sensors(scene, prefix, kin)
        if not rec.is_visual:
            _add_contact_sensors(scene, prefix, kin)
        prefixes.append(prefix)
    m = compile_spec(scene, objs[0].asset_file if objs else "scene")
    layouts = [_object_layout(m, config, *a) for a in zip(objs, kins, prefixes, strict=True)]
    for lay, armature in zip(layouts, ball_armature, strict=True):
        for jname, values in armature.items():  # per-axis hinge armature onto the ball's 3 DoFs
            j = m.joint(lay.prefix + jname).id
            m.dof_armature[m.jnt_dofadr[j] : m.jnt_dofadr[j] + 3] = values
    return m, layouts


def _object_layout(
    m: mujoco.MjModel, config: EngineConfig, rec: ObjRecord, kin: KinCharModel, prefix: str
) -> MjObjLayout:
    """Where object `rec` (attached under `prefix`) lives in the compiled model `m`."""
    body_ids = np.array([m.body(prefix + n).id for n in kin.body_names])
    root = int(body_ids[0])
    free = m.body_jntnum[root] == 1
    root_jnt = int(m.body_jntadr[root])
    actuated = has_motors(config.control_mode, rec, kin)
    act_names = _actuator_names(kin) if actuated else []
    lay = MjObjLayout(
        kin=kin,
        actuated=actuated,
        prefix=prefix,
        body_ids=body_ids,
        root_qpos=int(m.jnt_qposadr[root_jnt]) if free else -1,
        root_qvel=int(m.jnt_dofadr[root_jnt]) if free else -1,
        mocap_id=-1 if free else int(m.body_mocapid[root]),
        root_ipos=m.body_ipos[root].copy(),
        act_ids=np.array([m.actuator(prefix + a).id for a in act_names], dtype=np.int64),
        **_joint_columns(m, kin, body_ids),
        **_sensor_layout(m, rec, kin, prefix),
    )
    lay.kp, lay.kd = mode_gains(config.control_mode, kin, lay.actuated)
    return lay


def _joint_columns(m: mujoco.MjModel, kin: KinCharModel, body_ids: np.ndarray) -> dict[str, np.ndarray]:
    """`MjObjLayout`'s joint fields: for each non-root joint with DoFs, in joint order, its clip DoF
    columns and qpos addresses (hinges: one each and the unit axis; balls: 3 columns, 4 quaternion
    addresses), and the qvel addresses of all of them."""
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
    return {
        "dof_qvel": np.array(dof_qvel, dtype=np.int64),
        "hinge_cols": np.array(hinge_cols, dtype=np.int64),
        "hinge_qpos": np.array(hinge_qpos, dtype=np.int64),
        "ball_cols": np.array(ball_cols, dtype=np.int64).reshape(-1, 3),
        "ball_qpos": np.array(ball_qpos, dtype=np.int64).reshape(-1, 4),
        "hinge_joints": np.array(hinge_joints, dtype=np.int64),
        "hinge_axes": np.array(hinge_axes, dtype=np.float64).reshape(-1, 3),
        "ball_joints": np.array(ball_joints, dtype=np.int64),
    }


def _sensor_layout(m: mujoco.MjModel, rec: ObjRecord, kin: KinCharModel, prefix: str) -> dict[str, np.ndarray]:
    """`MjObjLayout`'s sensordata columns: each body's state sensors (quaternion columns in xyzw order)
    and, unless the object is visual only, each body's contact and ground sensors."""
    body_adr = [
        [col for suffix, _, _ in _BODY_SENSORS for col in _sensor_columns(m, f"{prefix}{n}_{suffix}")]
        for n in kin.body_names
    ]
    contact_adr, ground_adr = [], []
    if not rec.is_visual:
        for n in kin.body_names:
            contact_adr += _sensor_columns(m, f"{prefix}{n}_contact")
            ground_adr += _sensor_columns(m, f"{prefix}{n}_ground")
    return {
        "body_adr": np.array(body_adr, dtype=np.int64)[:, _WXYZ_TO_XYZW_COLUMNS],
        "contact_adr": np.array(contact_adr, dtype=np.int64),
        "ground_adr": np.array(ground_adr, dtype=np.int64),
    }


def _actuator_names(kin: KinCharModel) -> list[str]:
    return [f"{j.name}_{'xyz'[a]}" if j.dof_dim == 3 else j.name for j in kin.joints[1:] for a in range(j.dof_dim)]


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


def _sensor_columns(m: mujoco.MjModel, name: str) -> list[int]:
    s = m.sensor(name)
    return list(range(int(s.adr[0]), int(s.adr[0]) + int(s.dim[0])))
