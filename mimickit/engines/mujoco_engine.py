"""The MuJoCo (CPU) engine: one compiled MjModel shared by all envs, one MjData per env.

Build (`mujoco_scene.build_scene`): every object's MJCF adapted and attached under its own name prefix to
a scene with a floor, one actuator per DoF, state and contact sensors per body.

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

pd_explicit: τ = kp (q* − q) − kd q̇ per actuator, recomputed before every substep between `mj_step1`
(which computes the actuator lengths and velocities of the current state) and `mj_step2`. An actuator's
length is the hinge angle or, for a ball joint with gear e_i, exp-map component i; its velocity is q̇ or
the local angular velocity ω_i: the law the pos-mode actuators apply, with the damping explicit.
"""

from __future__ import annotations

import os
import queue
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from functools import partial

import mujoco
import numpy as np
import torch

from mimickit.engines.engine import ControlMode, Engine, EngineConfig, EnvIds, MujocoView, ViewObject
from mimickit.engines.engine_records import ObjState, state_shapes
from mimickit.engines.mujoco_scene import MjObjLayout, build_scene
from mimickit.util import torch_util as tu
from mimickit.util.np_rotation import cross, quat_rotate_wxyz, quat_wxyz_canonical, quat_wxyz_to_exp_map

# MjData fields gathered into stacked [N, ...] arrays after every step: the body states are sensors.
# (Actuator forces are read only when asked for: the envs never do.)
_GATHERED_FIELDS = ("qpos", "qvel", "sensordata")

GUIDED_SPLIT = 2
"""Each chunk of the step queue takes 1/(GUIDED_SPLIT × threads) of the envs still unassigned (at least
one): big chunks first, single envs last, so the threads finish within about one env's step of each
other (fixed chunks of 16 envs left one core idle ~2 ms per control step at 256 envs, measured)."""


# ---------------------------------------------------------------------------------------------- state
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
        self._pushed_envs: set[int] = set()  # envs whose xfrc_applied holds a push (see _body_forces_changed)

    def get_name(self) -> str:
        return "mujoco"

    def obj_layout(self, obj_id: int) -> MjObjLayout:
        """Where object `obj_id` lives in `mj_model` (its body, joint, actuator and sensor indices), for tools
        and tests that read the compiled model; the engine's own, not to be changed."""
        return self._layouts[obj_id]

    # ------------------------------------------------------------------ creation
    def _sim_initialized(self) -> bool:
        return self.mj_model is not None

    def initialize_sim(self) -> None:
        objs = self._check_env_objects()
        self.mj_model, self._layouts = build_scene(self._config, objs, [self._kin_model(o.asset_file) for o in objs])
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
        self._chunks = guided_chunks(self._num_envs, self._nthread)
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

    @contextmanager
    def stepping(self) -> Iterator[None]:
        """The block runs on the calling thread while the workers run the first pass of substeps."""
        self._push_edits()
        nsub = self._config.substeps
        if nsub > 1:
            # The sensors (our contact-force readout, ~6% of a substep) are read only after the last
            # substep: switch them off before it. The flag is flipped only while no worker runs.
            opt = self.mj_model.opt
            flags = opt.disableflags
            opt.disableflags = flags | mujoco.mjtDisableBit.mjDSBL_SENSOR
            try:
                with self._workers_running(nsub - 1, first=True, last=False):
                    yield
            finally:
                opt.disableflags = flags
            with self._workers_running(1, first=False, last=True):
                pass
        else:
            with self._workers_running(1, first=True, last=True):
                yield
        # Gather and refresh once here rather than per chunk in the workers: measured as fast or faster
        # (numpy ops in a worker hold the GIL that the other workers need between mj_step calls).
        self._gather(slice(None))
        self._refresh(slice(None))
        self._sim_time += self.get_timestep()
        self._count_body_force_step()

    @contextmanager
    def _workers_running(self, nstep: int, first: bool, last: bool) -> Iterator[None]:
        """Advance every env `nstep` substeps. The threads take chunks from one queue (see GUIDED_SPLIT);
        the calling thread runs the block first and then takes chunks too, so the envs it would have
        stepped go to whichever thread is free."""
        pd = self._config.control_mode == ControlMode.pd_explicit
        worker = partial(self._step_chunk_pd_explicit if pd else self._step_chunk, nstep=nstep, first=first, last=last)
        if self._pool is None:  # one thread, or closed
            yield
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
            yield
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

    def _body_forces_changed(self) -> None:
        """Rewrite the pushes into `xfrc_applied`, which MuJoCo keeps and applies on every substep until it
        is changed: zeroed in the envs that held one, then each push added at its body."""
        for e in self._pushed_envs:
            self.mj_datas[e].xfrc_applied[:] = 0.0
        self._pushed_envs = set()
        for f in self._body_forces.values():
            b = self._layouts[f.obj_id].body_ids[f.body_id]
            xfrc = self.mj_datas[f.env_id].xfrc_applied
            xfrc[b, :3] += f.force
            xfrc[b, 3:] += f.torque
            self._pushed_envs.add(f.env_id)

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

    def pending_edits(self) -> np.ndarray:
        """Per env, whether setter edits wait to be written into its MjData (by the next step or a getter
        that needs kinematics): a reset whose observations come from the state it set leaves them waiting."""
        return self._dirty.copy()

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
        self._end_body_forces(ids, obj_id)  # placed anew: a push does not carry over a reset
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
        self._end_body_forces(ids, obj_id)  # placed anew: a push does not carry over a reset
        qpos[ids, lay.root_qpos : lay.root_qpos + 3] = _rows(root_pos, n, 3)
        qpos[ids, lay.root_qpos + 3 : lay.root_qpos + 7] = rot[:, [3, 0, 1, 2]] / np.linalg.norm(
            rot, axis=-1, keepdims=True
        )
        self._write_root_vel(ids, lay, _rows(root_vel, n, 3), _rows(root_ang_vel, n, 3))
        self._dirty[ids] = True

    def _root_rot_wxyz(self, ids: np.ndarray, lay: MjObjLayout) -> np.ndarray:
        q = self._host["qpos"][ids, lay.root_qpos + 3 : lay.root_qpos + 7]
        return q / np.linalg.norm(q, axis=-1, keepdims=True)

    def _root_vel_world(self, ids: np.ndarray, lay: MjObjLayout) -> tuple[np.ndarray, np.ndarray]:
        """Current root (COM velocity, angular velocity), world frame, [n, 3] each, from the stacked qvel."""
        rot = self._root_rot_wxyz(ids, lay)
        qv = self._host["qvel"][ids, lay.root_qvel : lay.root_qvel + 6]
        ang_vel = quat_rotate_wxyz(rot, qv[:, 3:])
        vel = qv[:, :3] + cross(ang_vel, quat_rotate_wxyz(rot, lay.root_ipos))
        return vel, ang_vel

    def _write_root_vel(self, ids: np.ndarray, lay: MjObjLayout, vel: np.ndarray, ang_vel: np.ndarray) -> None:
        """Store world-frame (COM velocity, angular velocity) [n, 3] as MuJoCo free-joint qvel."""
        rot = self._root_rot_wxyz(ids, lay)
        qvel = self._host["qvel"]
        qvel[ids, lay.root_qvel : lay.root_qvel + 3] = vel - cross(ang_vel, quat_rotate_wxyz(rot, lay.root_ipos))
        inv = rot * np.array([1.0, -1.0, -1.0, -1.0])
        qvel[ids, lay.root_qvel + 3 : lay.root_qvel + 6] = quat_rotate_wxyz(inv, ang_vel)

    def _env_ids(self, env_ids: EnvIds) -> np.ndarray:
        if env_ids is None:
            return np.arange(self._num_envs)
        return np.asarray(_to_numpy(env_ids), dtype=np.int64).reshape(-1)

    # ------------------------------------------------------------------ viewers
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
def guided_chunks(n: int, nthread: int) -> list[slice]:
    """Contiguous env slices covering 0..n, each 1/(GUIDED_SPLIT × nthread) of what is left (at least 1)."""
    chunks, lo = [], 0
    while lo < n:
        size = max(1, -(-(n - lo) // (GUIDED_SPLIT * nthread)))
        chunks.append(slice(lo, lo + size))
        lo += size
    return chunks


def _update_kinematics(m: mujoco.MjModel, d: mujoco.MjData) -> None:
    """Body poses, COM frames and velocities, and the body state sensors, for the current qpos/qvel
    (contacts and the contact sensors, computed with the accelerations, are left as they are)."""
    mujoco.mj_kinematics(m, d)
    mujoco.mj_comPos(m, d)
    mujoco.mj_comVel(m, d)
    mujoco.mj_sensorPos(m, d)
    mujoco.mj_sensorVel(m, d)


def _refresh_obj(
    lay: MjObjLayout, out: dict[str, np.ndarray], h: dict[str, np.ndarray], rows: slice | np.ndarray, contacts: bool
) -> None:
    """Write one object's state rows `rows` of `out` (see `_ObjState`) from stacked MjData fields h[field]
    [n, ...] (float64, already restricted to those rows)."""
    body = h["sensordata"][:, lay.body_adr]  # [n, B, 13] (see MjObjLayout.body_adr)
    out["body_pos"][rows] = body[..., 0:3]
    out["body_rot"][rows] = body[..., 3:7]
    out["body_vel"][rows] = body[..., 7:10]
    out["body_ang_vel"][rows] = body[..., 10:13]

    if lay.num_dofs:
        qpos = h["qpos"]
        dof_pos = np.empty((qpos.shape[0], lay.num_dofs))
        dof_pos[:, lay.hinge_cols] = qpos[:, lay.hinge_qpos]
        ball = quat_wxyz_canonical(qpos[:, lay.ball_qpos])
        dof_pos[:, lay.ball_cols] = quat_wxyz_to_exp_map(ball)
        out["dof_pos"][rows] = dof_pos
        out["joint_rot"][rows] = _joint_rot(lay, qpos[:, lay.hinge_qpos], ball)
        out["dof_vel"][rows] = h["qvel"][:, lay.dof_qvel]

    if contacts and len(lay.contact_adr):
        n, nb = body.shape[0], lay.num_bodies
        # The sensors report the force their body exerts on the others: negate for the force on the body.
        out["contact_forces"][rows] = 0.0 - h["sensordata"][:, lay.contact_adr].reshape(n, nb, 3)
        out["ground_contact_forces"][rows] = 0.0 - h["sensordata"][:, lay.ground_adr].reshape(n, nb, 3)


def _joint_rot(lay: MjObjLayout, hinge_angle: np.ndarray, ball_wxyz: np.ndarray) -> np.ndarray:
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
