"""The Newton engine: N worlds of one scene stepped by Newton's SolverMuJoCo (mujoco_warp).

Build (as the reference's Newton engine, on the Newton 1.8 API): each distinct object gets one
sub-builder from its MJCF (`add_mjcf`, 3-hinge bodies → one ball joint, as the MuJoCo engine does);
every env is one Newton world
(`begin_world` / `add_builder` / `end_world`) next to one global ground plane; `finalize` on the warp
device (the CPU here; CUDA where there is one). PD gains come from the MJCF joint stiffness/damping via
the kinematic model (the same numbers the MuJoCo engine uses); they are moved into Newton's joint-target
gains and the passive stiffness/damping is zeroed **before** the solver is built, since SolverMuJoCo
creates its MuJoCo actuators at construction.

Differences from the reference Newton engine (its defects, fixed here):
* `disable_motors` is honoured: the object's DoFs get no actuator (JointTargetMode.NONE).
* `pd_explicit` computes τ = kp (q* − q) − kd q̇ in torch on DoF-sized tensors [N, D] (not on mixed q/qd
  warp arrays): q holds hinge angles and ball-joint exp-maps, q̇ hinge rates and ball-joint local angular
  velocities (the law of the MuJoCo engine's actuators). τ is clipped to the torque limit and applied
  through `control.joint_f` before every substep.
* Torque commands are clipped to the torque limit (Newton's EFFORT mode applies joint_f unclipped).
* Ball joints get the cone limit of `ball_joint_limits` (Newton's MuJoCo conversion makes every ball joint
  unlimited): the same MuJoCo constraint as in the MuJoCo engine, see `_set_ball_limits`.

State: the solver steps the state in place; after a control step the raw warp arrays (joint_q, joint_qd,
body_q, body_qd, as zero-copy torch views) are converted into per-object torch buffers, which the
getters return (they are refreshed in place, so they stay live). Newton already uses the framework's
conventions: quaternions xyzw, free-joint and body linear velocities at the centre of mass in world
frame, angular velocities in world frame. Two conversions remain for ball joints: quaternions are exposed
as exp-maps, and Newton's ball joint_qd / joint_f are angular velocity / torque in the *parent* frame
(SolverMuJoCo maps MuJoCo's qvel = r⁻¹ joint_qd, r the joint rotation), which the engine rotates into the
child frame of the engine contract (docs/architecture.md) and the MuJoCo engine (dof_vel, torque
commands, dof_forces). Setters write joint_q/joint_qd and mark the state dirty; the next getter or step
re-runs forward kinematics.

Fixed-root objects (`fix_root`) are welded where `create_obj` put them: root setters leave them there (the
MuJoCo engine moves them as mocap bodies; the reference edits `joint_X_p` behind the solver's back).

Ground contact forces: `SensorContact` on every body of the non-visual objects with the ground plane as
the one counterpart, fed by the solver's CONTACT_F observable after the last substep.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

import mujoco
import numpy as np
import torch

from mimickit.anim.kin_char_model import JointType
from mimickit.engines.engine import ControlMode, Engine, EngineConfig, EnvIds, MujocoView, has_motors, mode_gains
from mimickit.engines.engine_records import ObjLayout, ObjRecord, ObjState
from mimickit.util import torch_util as tu
from mimickit.util.errors import MimicKitError

if TYPE_CHECKING:
    from mimickit.engines.mujoco_mirror import MujocoMirror

try:  # an optional extra: the builder reports a missing install with the command that fixes it
    import warp as wp

    # Before newton initialises warp: no banner or per-module load lines on stdout (`sim2sim --json`).
    wp.config.log_level = max(wp.config.log_level, wp.LOG_WARNING)
    import newton
    from newton.sensors import SensorContact
except ImportError as exc:  # pragma: no cover - exercised only without the extra
    raise ImportError(
        "the Newton engine needs the optional extra: pip install -e '.[newton]' (in its own venv, "
        "e.g. `make test-newton` builds .venv-newton; newton[sim] pins mujoco 3.17)"
    ) from exc

wp.config.enable_backward = False  # no gradients: smaller, faster kernels

GROUND_LABEL = "ground_plane"


# ---------------------------------------------------------------------------------------------- records
@dataclass(kw_only=True)
class _ObjLayout(ObjLayout):
    """Where an object lives inside one world. Indices are per world (add `world * stride`)."""

    bodies: slice  # body rows
    root_q: int  # joint_q column of the free root joint, -1 for a fixed root
    root_qd: int  # its joint_qd column, -1 for a fixed root
    hinge_cols: torch.Tensor  # [H] DoF columns of hinges
    hinge_q: torch.Tensor  # [H] their joint_q columns
    ball_cols: torch.Tensor  # [K, 3] DoF columns of ball joints (exp-map components)
    ball_q: torch.Tensor  # [K, 4] their joint_q columns (quaternion xyzw)
    ball_qd: torch.Tensor  # [K, 3] their joint_qd columns (parent-frame angular velocity)
    ball_joints: list[int]  # [K] their Newton joint indices (world 0)
    ball_cones: list[float | None]  # [K] their cone limits (rad), None = unlimited
    dof_qd: torch.Tensor  # [D] joint_qd column of every DoF


# ---------------------------------------------------------------------------------------------- engine
class NewtonEngine(Engine):
    """Newton (SolverMuJoCo) on the warp device; see the module docstring. Tensor shapes as in `Engine`."""

    def __init__(self, config: EngineConfig, num_envs: int, device: torch.device | str, visualize: bool = False):
        super().__init__(config, num_envs, device, visualize)
        # warp runs on CUDA only when the torch device is CUDA; kernels otherwise compile for the CPU
        self._wp_device = "cuda:0" if self._device.type == "cuda" else "cpu"
        self.model = None
        self._mirror: MujocoMirror | None = None  # mujoco_view's MuJoCo copy of the scene, built on first use

    def get_name(self) -> str:
        return "newton"

    # ------------------------------------------------------------------ creation
    def _sim_initialized(self) -> bool:
        return self.model is not None

    def initialize_sim(self) -> None:
        objs = self._check_env_objects()
        self.model = self._build_model(objs)
        self._layouts = self._build_layouts(objs)
        self._set_gains(objs)  # before the solver: SolverMuJoCo builds its actuators from these
        self._set_ball_limits()  # before the solver too: it copies the limits at construction
        self._float_ghosts(objs)
        self._build_solver()
        self._enable_ball_limits()
        self._bind_state()
        self._place_start_poses()
        n = self._num_envs
        self._states = [ObjState.zeros(n, lay.num_bodies, lay.num_dofs, self._device) for lay in self._layouts]
        self._cmd = [torch.zeros(self._num_envs, lay.num_dofs, device=self._device) for lay in self._layouts]
        self._tau = [torch.zeros(self._num_envs, lay.num_dofs, device=self._device) for lay in self._layouts]
        self._gains = [self._torch_gains(lay) for lay in self._layouts]
        self._dirty = True
        self._refresh()
        if self._config.control_mode == ControlMode.pd_explicit:
            self._check_explicit_damping()

    def _check_explicit_damping(self) -> None:
        """Warn when pd_explicit's damping is too stiff for the timestep (mass matrix of the solver's MuJoCo
        template world in the model's initial pose)."""
        m, d = self.solver.mj_model, self.solver.mj_data
        full = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, full)
        to_mj = {int(n): i for i, n in enumerate(self.solver.mjc_dof_to_newton_dof.numpy()[0]) if n >= 0}
        for lay in self._layouts:
            if lay.actuated:
                rows = [to_mj[int(c)] for c in lay.dof_qd]
                self._warn_explicit_damping(lay.kin, lay.kd, full[rows, rows])

    def _new_builder(self) -> newton.ModelBuilder:
        b = newton.ModelBuilder()
        newton.solvers.SolverMuJoCo.register_custom_attributes(b)
        b.default_shape_cfg.mu = 1.0  # the MuJoCo engine's floor friction
        return b

    def _object_builder(self, rec: ObjRecord, pose: tuple[np.ndarray, np.ndarray]) -> newton.ModelBuilder:
        b = self._new_builder()
        pos, rot = pose
        b.add_mjcf(
            rec.asset_file,
            xform=wp.transform(wp.vec3(*pos), wp.quat(*rot)),
            floating=not rec.fix_root,
            enable_self_collisions=rec.enable_self_collisions,
            convert_3d_hinge_to_ball_joints=True,
            collapse_fixed_joints=False,
            ignore_inertial_definitions=False,
            ignore_names=["floor", "ground"],
        )
        if rec.is_visual:  # a ghost: drawn, never touching anything
            collide = int(newton.ShapeFlags.COLLIDE_SHAPES) | int(newton.ShapeFlags.COLLIDE_PARTICLES)
            b.shape_flags = [int(f) & ~collide for f in b.shape_flags]
        return b

    def _build_model(self, objs: list[ObjRecord]):
        scene = self._new_builder()
        scene.add_ground_plane(cfg=newton.ModelBuilder.ShapeConfig(mu=1.0, restitution=0.0), label=GROUND_LABEL)
        cache: dict[tuple, newton.ModelBuilder] = {}
        for e in range(self._num_envs):
            scene.begin_world()
            for rec, pose in zip(objs, self._start_poses[e], strict=True):
                if rec.fix_root:  # a fixed root's pose is part of the model
                    scene.add_builder(self._object_builder(rec, pose))
                    continue
                if rec.signature() not in cache:
                    cache[rec.signature()] = self._object_builder(rec, (np.zeros(3), np.array([0, 0, 0, 1.0])))
                scene.add_builder(cache[rec.signature()])
            scene.end_world()
        return scene.finalize(device=self._wp_device, requires_grad=False)

    def _build_layouts(self, objs: list[ObjRecord]) -> list[_ObjLayout]:
        m, n = self.model, self._num_envs
        self._bodies_per_world = m.body_count // n
        self._q_per_world = m.joint_coord_count // n
        self._qd_per_world = m.joint_dof_count // n
        art = m.articulation_start.numpy()
        joint_q_start, joint_qd_start = m.joint_q_start.numpy(), m.joint_qd_start.numpy()
        joint_child = m.joint_child.numpy()
        layouts, body0 = [], 0
        for o, rec in enumerate(objs):
            kin = self._kin_model(rec.asset_file)
            j0 = int(art[o])  # articulations of env 0 come first, one per object
            nb = kin.get_num_joints()
            names = [str(s).rsplit("/", 1)[-1] for s in m.body_label[body0 : body0 + nb]]
            if names != kin.body_names:
                raise MimicKitError(f"{rec.asset_file}: Newton body order {names} differs from {kin.body_names}")
            hinge_cols, hinge_q, ball_cols, ball_q, ball_qd, ball_joints, ball_cones = [], [], [], [], [], [], []
            dof_qd = []
            for joint in kin.joints[1:]:
                if joint.dof_dim == 0:
                    continue
                nj = j0 + joint.body_id  # one Newton joint per body, in body order
                assert joint_child[nj] == body0 + joint.body_id
                q0, qd0 = int(joint_q_start[nj]), int(joint_qd_start[nj])
                if joint.type == JointType.HINGE:
                    hinge_cols.append(joint.dof_idx)
                    hinge_q.append(q0)
                    dof_qd.append(qd0)
                else:
                    ball_cols.append([joint.dof_idx + k for k in range(3)])
                    ball_q.append([q0 + k for k in range(4)])
                    ball_qd.append([qd0 + k for k in range(3)])
                    ball_joints.append(nj)
                    ball_cones.append(self._ball_cone(joint.low, joint.high))
                    dof_qd += [qd0 + k for k in range(3)]
            lay = _ObjLayout(
                kin=kin,
                bodies=slice(body0, body0 + nb),
                root_q=-1 if rec.fix_root else int(joint_q_start[j0]),
                root_qd=-1 if rec.fix_root else int(joint_qd_start[j0]),
                hinge_cols=torch.tensor(hinge_cols, dtype=torch.long),
                hinge_q=torch.tensor(hinge_q, dtype=torch.long),
                ball_cols=torch.tensor(ball_cols, dtype=torch.long).reshape(-1, 3),
                ball_q=torch.tensor(ball_q, dtype=torch.long).reshape(-1, 4),
                ball_qd=torch.tensor(ball_qd, dtype=torch.long).reshape(-1, 3),
                ball_joints=ball_joints,
                ball_cones=ball_cones,
                dof_qd=torch.tensor(dof_qd, dtype=torch.long),
                actuated=has_motors(self._config.control_mode, rec, kin),
            )
            lay.kp, lay.kd = mode_gains(self._config.control_mode, kin, lay.actuated)
            layouts.append(lay)
            body0 += nb
        return layouts

    def _target_mode(self, lay: _ObjLayout) -> int:
        mode = self._config.control_mode
        if not lay.actuated:
            return int(newton.JointTargetMode.NONE)
        return int({
            ControlMode.pos: newton.JointTargetMode.POSITION,
            ControlMode.vel: newton.JointTargetMode.VELOCITY,
        }.get(mode, newton.JointTargetMode.EFFORT))  # fmt: skip

    def _set_gains(self, objs: list[ObjRecord]) -> None:
        """Joint-target gains, modes and effort limits per DoF in every world; passive springs off."""
        m = self.model
        ke, kd = m.joint_target_ke.numpy(), m.joint_target_kd.numpy()
        mode, limit = m.joint_target_mode.numpy(), m.joint_effort_limit.numpy()
        ke[:], kd[:], mode[:] = 0.0, 0.0, int(newton.JointTargetMode.NONE)
        for lay in self._layouts:
            cols = (lay.dof_qd.numpy()[None] + self._qd_per_world * np.arange(self._num_envs)[:, None]).ravel()
            ke[cols] = np.tile(lay.kp, self._num_envs)
            kd[cols] = np.tile(lay.kd, self._num_envs)
            mode[cols] = self._target_mode(lay)
            limit[cols] = np.tile(lay.kin.dof_array("torque_limit"), self._num_envs)
        m.joint_target_ke.assign(ke)
        m.joint_target_kd.assign(kd)
        m.joint_target_mode.assign(mode)
        m.joint_effort_limit.assign(limit)
        # The MJCF stiffness/damping are the PD gains (as in the reference), not springs: zero the passive ones.
        m.joint_stiffness.zero_()
        m.joint_damping.zero_()

    def _set_ball_limits(self) -> None:
        """Cone limits, step 1 (before the solver): SolverMuJoCo copies a ball joint's DoF limits into its
        MuJoCo jnt_range, whose cone angle is max(range), at construction and on every later
        `notify_model_changed`. Each DoF of a limited ball joint gets ±cone, so that max is the cone."""
        lower, upper = self.model.joint_limit_lower.numpy(), self.model.joint_limit_upper.numpy()
        world_offsets = self._qd_per_world * np.arange(self._num_envs)[:, None]
        for lay in self._layouts:
            for cols, cone in zip(lay.ball_qd.numpy(), lay.ball_cones, strict=True):
                if cone is not None:
                    rows = (cols[None] + world_offsets).ravel()
                    lower[rows], upper[rows] = -cone, cone
        self.model.joint_limit_lower.assign(lower)
        self.model.joint_limit_upper.assign(upper)

    def _enable_ball_limits(self) -> None:
        """Cone limits, step 2 (after the solver): SolverMuJoCo compiles every ball joint with limited=False.
        Flag the limited ones in its MuJoCo model and in the MuJoCo-Warp copy, whose ball-limit kernel runs
        over the index list `jnt_limited_ball_adr` (built from jnt_limited when the model was uploaded)."""
        cones = {j: c for lay in self._layouts for j, c in zip(lay.ball_joints, lay.ball_cones, strict=True)}
        mj_to_newton = self.solver.mjc_jnt_to_newton_jnt.numpy()[0]  # MuJoCo joint → Newton joint (world 0)
        ids = [i for i, j in enumerate(mj_to_newton) if cones.get(int(j)) is not None]
        if not ids:
            return
        mj, mjw = self.solver.mj_model, self.solver.mjw_model
        mj.jnt_limited[ids] = 1
        mj.jnt_range[ids] = [(0.0, cones[int(mj_to_newton[i])]) for i in ids]
        limited_balls = np.flatnonzero(mj.jnt_limited & (mj.jnt_type == mujoco.mjtJoint.mjJNT_BALL))
        device = mjw.jnt_limited.device
        mjw.jnt_limited = wp.array(mj.jnt_limited.astype(np.int32), dtype=wp.int32, device=device)
        mjw.jnt_limited_ball_adr = wp.array(limited_balls.astype(np.int32), dtype=wp.int32, device=device)

    def _torch_gains(self, lay: _ObjLayout) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(kp, kd, torque limit) [D] of an object as float tensors on the env device."""
        arrays = (lay.kp, lay.kd, lay.kin.dof_array("torque_limit"))
        kp, kd, limit = (torch.as_tensor(a, dtype=torch.float32, device=self._device) for a in arrays)
        return kp, kd, limit

    def _float_ghosts(self, objs: list[ObjRecord]) -> None:
        """Visual objects get MuJoCo gravity compensation (as in the MuJoCo engine): a ghost stays where the
        env poses it instead of dropping during each control step."""
        gravcomp = self.model.mujoco.gravcomp.numpy()
        for rec, lay in zip(objs, self._layouts, strict=True):
            if rec.is_visual:
                for e in range(self._num_envs):
                    start = e * self._bodies_per_world
                    gravcomp[start + lay.bodies.start : start + lay.bodies.stop] = 1.0
        self.model.mujoco.gravcomp.assign(gravcomp)

    def _build_solver(self) -> None:
        cfg, m = self._config, self.model
        self.solver = newton.solvers.SolverMuJoCo(
            m,
            solver="newton",
            integrator=cfg.integrator,
            cone="pyramidal",
            impratio=10.0,
            iterations=cfg.solver_iterations,
            ls_iterations=cfg.ls_iterations,
            # Per-world contact and constraint capacity: the reference engine's sizes.
            nconmax=150,
            njmax=450,
        )
        self._sensor_rows = self._sensor_layout()
        kinds = {newton.solvers.SolverMuJoCo.ObservableKind.QFRC_ACTUATOR}
        self.sensor = None  # a scene of ghosts only has no body to sense
        if self._sensor_bodies:
            self.sensor = SensorContact(
                m,
                sensing_bodies=self._sensor_bodies,
                counterpart_shapes=[list(m.shape_label).index(GROUND_LABEL)],
                measure_total=True,
                request_contact_attributes=False,
            )
            kinds |= set(self.sensor.solver_observable_kinds)
        # MuJoCo finds the contacts itself; this buffer only receives them (and their forces) for the sensor.
        capacity = self.solver.get_max_contact_count()
        self.contacts = newton.CollisionPipeline(m, rigid_contact_max=capacity, soft_contact_max=0).contacts()
        self.observables = self.solver.observables(kinds=kinds, contacts=self.contacts)
        self.state = m.state()
        self.control = m.control()
        newton.eval_fk(m, m.joint_q, m.joint_qd, self.state)

    def _sensor_layout(self) -> list[tuple[int, torch.Tensor]]:
        """Contact-sensor bodies (all bodies of non-visual objects, every world, ascending) and, per object,
        (obj_id, row index [N, B] into the sensor's outputs)."""
        bodies, rows = [], []
        for o, (rec, lay) in enumerate(zip(self._env_objs[0], self._layouts, strict=True)):
            if rec.is_visual:
                continue
            per_world = np.arange(lay.bodies.start, lay.bodies.stop)
            ids = per_world[None] + self._bodies_per_world * np.arange(self._num_envs)[:, None]  # [N, B]
            rows.append((o, ids))
            bodies.append(ids.ravel())
        self._sensor_bodies = sorted(int(b) for b in np.concatenate(bodies)) if bodies else []
        pos = {b: i for i, b in enumerate(self._sensor_bodies)}
        return [(o, torch.from_numpy(np.vectorize(pos.get)(ids)).long()) for o, ids in rows]

    def _bind_state(self) -> None:
        """Zero-copy torch views [N, ...] of the warp state, control and model arrays."""
        n = self._num_envs
        s, c = self.state, self.control
        self._jq = wp.to_torch(s.joint_q).view(n, -1)
        self._jqd = wp.to_torch(s.joint_qd).view(n, -1)
        self._body_f = wp.to_torch(s.body_f).view(-1, 6)  # every world's bodies, one row each
        self._bq = wp.to_torch(s.body_q).view(n, self._bodies_per_world, 7)
        self._bqd = wp.to_torch(s.body_qd).view(n, self._bodies_per_world, 6)
        self._target_q = wp.to_torch(c.joint_target_q).view(n, -1)
        self._target_qd = wp.to_torch(c.joint_target_qd).view(n, -1)
        self._joint_f = wp.to_torch(c.joint_f).view(n, -1)
        self._qfrc = wp.to_torch(self.observables.qfrc_actuator).view(n, -1)

    def _place_start_poses(self) -> None:
        """Free roots start at their env's start pose (fixed roots got theirs in the model)."""
        for e, poses in enumerate(self._start_poses):
            for lay, (pos, rot) in zip(self._layouts, poses, strict=True):
                if lay.root_q >= 0:
                    self._jq[e, lay.root_q : lay.root_q + 3] = torch.from_numpy(pos)
                    self._jq[e, lay.root_q + 3 : lay.root_q + 7] = torch.from_numpy(rot)
        newton.eval_fk(self.model, self.state.joint_q, self.state.joint_qd, self.state)

    # ------------------------------------------------------------------ stepping
    def set_cmd(self, obj_id: int, cmd: torch.Tensor) -> None:
        lay = self._layouts[obj_id]
        if self._config.control_mode == ControlMode.none or not lay.actuated:
            return
        value = torch.as_tensor(cmd, dtype=torch.float32).to(self._device).expand(self._num_envs, lay.num_dofs)
        self._cmd[obj_id][:] = value
        mode = self._config.control_mode
        if mode == ControlMode.pos:
            self._target_q[:, lay.hinge_q] = value[:, lay.hinge_cols]
            if len(lay.ball_cols):  # ball targets are quaternions; the solver turns them back into exp-maps
                self._target_q[:, lay.ball_q] = tu.exp_map_to_quat(value[:, lay.ball_cols])
        elif mode == ControlMode.vel:
            self._target_qd[:, lay.dof_qd] = value
        elif mode == ControlMode.torque:
            limit = self._gains[obj_id][2]
            self._tau[obj_id][:] = torch.maximum(torch.minimum(value, limit), -limit)
            self._write_joint_f(lay, self._tau[obj_id])

    @contextmanager
    def stepping(self) -> Iterator[None]:
        self._sync()
        dt = self.get_sim_timestep()
        nsub = self._config.substeps
        pushes = self._body_force_rows()
        for i in range(nsub):
            self.state.clear_forces()
            if pushes is not None:  # body_f is cleared above: the pushes go in again before each substep
                self._body_f[pushes[0]] = pushes[1]
            if self._config.control_mode == ControlMode.pd_explicit:
                self._apply_explicit_pd()
            elif self._config.control_mode == ControlMode.torque:
                self._rotate_ball_torques()  # a child-frame torque turns with the joint
            # Contact forces are exported only on the last substep: that is all the sensor reads.
            obs = self.observables if i == nsub - 1 else None
            self.solver.step(self.state, self.state, self.control, self.contacts, dt, observables=obs)
        if self.sensor is not None:
            self.sensor.update(self.state, self.contacts, observables=self.observables)
        yield  # on a GPU the kernels above are queued, not yet run: the block overlaps them
        self._refresh(contacts=True)
        self._sim_time += self.get_timestep()
        self._count_body_force_step()

    def _body_force_rows(self) -> tuple[torch.Tensor, torch.Tensor] | None:
        """The pushes of this control step as (body_f rows [P], wrenches [P, 6]: force then torque, world
        frame at the centre of mass, as Newton's body_f takes them), or None without any."""
        if not self._body_forces:
            return None
        per_world = self._bodies_per_world
        rows, wrenches = [], []
        for f in self._body_forces.values():
            rows.append(f.env_id * per_world + self._layouts[f.obj_id].bodies.start + f.body_id)
            wrenches.append(np.concatenate([f.force, f.torque]))
        return (
            torch.tensor(rows, dtype=torch.long, device=self._device),
            torch.tensor(np.stack(wrenches), dtype=torch.float32, device=self._device),
        )

    def _apply_explicit_pd(self) -> None:
        """τ = kp (q* − q) − kd q̇ on the [N, D] DoF vectors of the current state (ball joints: exp-map and
        local angular velocity), clipped to ± the torque limit, into control.joint_f."""
        for o, (lay, cmd) in enumerate(zip(self._layouts, self._cmd, strict=True)):
            if not lay.actuated:
                continue
            kp, kd, limit = self._gains[o]
            tau = kp * (cmd - self._dof_pos(lay)) - kd * self._dof_vel(lay)
            self._tau[o][:] = torch.maximum(torch.minimum(tau, limit), -limit)
            self._write_joint_f(lay, self._tau[o])

    def _rotate_ball_torques(self) -> None:
        """Re-express the torque-mode ball-joint torques in the parent frame of the joints' current rotation."""
        for lay, tau in zip(self._layouts, self._tau, strict=True):
            if lay.actuated and len(lay.ball_cols):
                self._write_joint_f(lay, tau)

    def _write_joint_f(self, lay: _ObjLayout, tau: torch.Tensor) -> None:
        """Local-frame DoF torques [N, D] into control.joint_f (ball joints: rotated into Newton's parent frame)."""
        self._joint_f[:, lay.dof_qd] = tau
        if len(lay.ball_cols):
            self._joint_f[:, lay.ball_qd] = tu.quat_rotate(self._ball_rot(lay), tau[:, lay.ball_cols])

    # ------------------------------------------------------------------ DoF coordinates of the warp state
    def _ball_rot(self, lay: _ObjLayout, ids: torch.Tensor | slice = slice(None)) -> torch.Tensor:
        """[n, K, 4] current ball-joint rotations (xyzw, normalised) of env rows `ids`."""
        return tu.quat_normalize(self._jq[ids][:, lay.ball_q])

    def _dof_pos(self, lay: _ObjLayout) -> torch.Tensor:
        """[N, D] hinge angles and ball-joint exp-maps of the current joint_q."""
        pos = torch.empty(self._num_envs, lay.num_dofs, device=self._device)
        pos[:, lay.hinge_cols] = self._jq[:, lay.hinge_q]
        if len(lay.ball_cols):
            pos[:, lay.ball_cols] = tu.quat_to_exp_map(self._jq[:, lay.ball_q])
        return pos

    def _dof_vel(self, lay: _ObjLayout, ids: torch.Tensor | slice = slice(None)) -> torch.Tensor:
        """[n, D] DoF velocities of env rows `ids`: hinge rates, ball-joint angular velocities in the child
        frame (Newton's joint_qd holds them in the parent frame)."""
        vel = self._jqd[ids][:, lay.dof_qd]
        if len(lay.ball_cols):
            vel[:, lay.ball_cols] = tu.quat_rotate_inverse(self._ball_rot(lay, ids), self._jqd[ids][:, lay.ball_qd])
        return vel

    def _write_ball_vel(self, lay: _ObjLayout, ids: torch.Tensor, local: torch.Tensor) -> None:
        """Child-frame ball-joint angular velocities [n, K, 3] of env rows `ids` into joint_qd (parent frame)."""
        self._jqd[ids[:, None, None], lay.ball_qd[None]] = tu.quat_rotate(self._ball_rot(lay, ids), local)

    # ------------------------------------------------------------------ state sync
    def _sync(self) -> None:
        """Forward kinematics after setter edits, so body poses and velocities match joint_q / joint_qd."""
        if self._dirty:
            newton.eval_fk(self.model, self.state.joint_q, self.state.joint_qd, self.state)
            self._refresh()

    def _refresh(self, contacts: bool = False) -> None:
        """Recompute every object's getter tensors from the warp state (in place: the tensors stay live)."""
        self._dirty = False
        for lay, st in zip(self._layouts, self._states, strict=True):
            t, b = st.tensors, lay.bodies
            t["body_pos"].copy_(self._bq[:, b, :3])
            t["body_rot"].copy_(self._bq[:, b, 3:])
            t["body_vel"].copy_(self._bqd[:, b, :3])
            t["body_ang_vel"].copy_(self._bqd[:, b, 3:])
            if lay.num_dofs:
                t["dof_pos"].copy_(self._dof_pos(lay))
                t["dof_vel"].copy_(self._dof_vel(lay))
        if contacts and self.sensor is not None:
            ground = wp.to_torch(self.sensor.force_matrix)[:, 0]  # [rows, 3]: the ground is counterpart 0
            total = wp.to_torch(self.sensor.total_force)
            for o, rows in self._sensor_rows:
                self._states[o].tensors["ground_contact_forces"].copy_(ground[rows])
                self._states[o].tensors["contact_forces"].copy_(total[rows])

    # ------------------------------------------------------------------ viewers
    def mujoco_view(self, env_id: int = 0) -> MujocoView:
        """Env `env_id` in a MuJoCo copy of the scene posed from this engine's state (`MujocoMirror`):
        SolverMuJoCo's own `mj_model` leaves out the geoms that do not collide, the whole reference character."""
        i = self._check_view_env(env_id)
        if self._mirror is None:
            from mimickit.engines.mujoco_mirror import MujocoMirror  # builds a MuJoCo model

            objects = [  # a record's fields are create_obj's keyword arguments
                {**asdict(rec), "start_pos": pos, "start_rot": rot}
                for rec, (pos, rot) in zip(self._env_objs[i], self._start_poses[i], strict=True)
            ]
            self._mirror = MujocoMirror(self, objects)
        return self._mirror.view(i)

    # ------------------------------------------------------------------ getters
    def _state_tensor(self, obj_id: int, name: str) -> torch.Tensor:
        self._sync()
        return self._states[obj_id].tensors[name]

    def get_dof_forces(self, obj_id: int) -> torch.Tensor:
        """[N, D] generalized actuator forces of the last substep (MuJoCo's qfrc_actuator), or the explicit
        joint torques applied in torque / pd_explicit mode; ball joints' in their child frame."""
        lay, t = self._layouts[obj_id], self._state_tensor(obj_id, "dof_forces")
        if self._config.control_mode in (ControlMode.torque, ControlMode.pd_explicit):
            t.copy_(self._tau[obj_id])
            return t
        t.copy_(self._qfrc[:, lay.dof_qd])
        if len(lay.ball_cols):  # Newton reports them in the parent frame, like joint_f
            t[:, lay.ball_cols] = tu.quat_rotate_inverse(self._ball_rot(lay), self._qfrc[:, lay.ball_qd])
        return t

    # ------------------------------------------------------------------ setters
    def _ids(self, env_ids: EnvIds) -> torch.Tensor:
        if env_ids is None:
            return torch.arange(self._num_envs)
        return torch.as_tensor(env_ids, dtype=torch.long).to(self._device).reshape(-1)

    def _rows(self, value: torch.Tensor | float, n: int, width: int) -> torch.Tensor:
        return torch.as_tensor(value, dtype=torch.float32).to(self._device).expand(n, width)

    def _set_root(self, env_ids: EnvIds, obj_id: int, value: torch.Tensor | float, width: int, offset: int,
                  in_qd: bool) -> None:  # fmt: skip
        lay = self._layouts[obj_id]
        if lay.root_q < 0:
            return  # a fixed root is part of the model
        ids = self._ids(env_ids)
        rows = self._rows(value, len(ids), width)
        if in_qd:  # free joint qd: COM linear velocity then angular velocity, both world frame
            self._jqd[ids, lay.root_qd + offset : lay.root_qd + offset + width] = rows
        else:
            self._jq[ids, lay.root_q + offset : lay.root_q + offset + width] = rows
        self._dirty = True

    def set_root_pos(self, env_ids: EnvIds, obj_id: int, root_pos: torch.Tensor | float) -> None:
        self._end_body_forces(self._ids(env_ids), obj_id)  # placed anew: a push does not carry over a reset
        self._set_root(env_ids, obj_id, root_pos, 3, 0, in_qd=False)

    def set_root_rot(self, env_ids: EnvIds, obj_id: int, root_rot: torch.Tensor | float) -> None:
        rot = tu.quat_normalize(torch.as_tensor(root_rot, dtype=torch.float32))
        self._set_root(env_ids, obj_id, rot, 4, 3, in_qd=False)

    def set_root_vel(self, env_ids: EnvIds, obj_id: int, root_vel: torch.Tensor | float) -> None:
        self._set_root(env_ids, obj_id, root_vel, 3, 0, in_qd=True)

    def set_root_ang_vel(self, env_ids: EnvIds, obj_id: int, root_ang_vel: torch.Tensor | float) -> None:
        self._set_root(env_ids, obj_id, root_ang_vel, 3, 3, in_qd=True)

    def set_dof_pos(self, env_ids: EnvIds, obj_id: int, dof_pos: torch.Tensor | float) -> None:
        ids, lay = self._ids(env_ids), self._layouts[obj_id]
        dof = self._rows(dof_pos, len(ids), lay.num_dofs)
        if len(lay.hinge_cols):
            self._jq[ids[:, None], lay.hinge_q[None]] = dof[:, lay.hinge_cols]
        if len(lay.ball_cols):
            # The child-frame velocities stay as they were (as in MuJoCo), in whichever order the setters run.
            local = self._dof_vel(lay, ids)[:, lay.ball_cols]
            self._jq[ids[:, None, None], lay.ball_q[None]] = tu.exp_map_to_quat(dof[:, lay.ball_cols])
            self._write_ball_vel(lay, ids, local)
        self._dirty = True

    def set_dof_vel(self, env_ids: EnvIds, obj_id: int, dof_vel: torch.Tensor | float) -> None:
        ids, lay = self._ids(env_ids), self._layouts[obj_id]
        vel = self._rows(dof_vel, len(ids), lay.num_dofs)
        self._jqd[ids[:, None], lay.dof_qd[None]] = vel
        if len(lay.ball_cols):
            self._write_ball_vel(lay, ids, vel[:, lay.ball_cols])
        self._dirty = True

    # ------------------------------------------------------------------ queries
    def get_gravity(self) -> np.ndarray:
        return np.asarray(self.model.gravity.numpy(), dtype=np.float64).reshape(-1, 3)[0].copy()

    def calc_obj_mass(self, env_id: int, obj_id: int) -> float:
        lay = self._layouts[obj_id]
        start = env_id * self._bodies_per_world
        return float(self.model.body_mass.numpy()[start + lay.bodies.start : start + lay.bodies.stop].sum())
