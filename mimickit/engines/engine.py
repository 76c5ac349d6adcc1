"""The engine interface: physics only (the reference's engine API and conventions).

An engine holds `N` independent worlds ("envs"), each with the same list of objects (character = 0,
reference "ghost" character = 1 when visualised, then markers and props). It takes per-DoF commands,
advances `sim_freq / control_freq` substeps per `step()`, and answers state queries as batched torch
tensors `[N, ...]` on the env device.

Shapes: `N` envs, `B` bodies of an object (kinematic DFS order), `D` DoFs of an object (root excluded),
`n` = number of selected envs (`env_ids`). Quaternions are (x, y, z, w). Positions are env-local; linear
and angular velocities are world-frame; a body's or root's linear velocity is that of its centre of mass.
Getters return live views: after `step()` (or any setter followed by a getter) they hold fresh values.
"""

from __future__ import annotations

import abc
import math
from contextlib import AbstractContextManager
from dataclasses import dataclass
from enum import IntEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import torch
from pydantic import Field, field_validator, model_validator

from mimickit.anim.kin_char_model import KinCharModel
from mimickit.anim.mjcf_char_model import load_char_model
from mimickit.engines.engine_records import ObjLayout, ObjRecord, ObjType
from mimickit.util.config import ConfigModel, parse_config
from mimickit.util.errors import MimicKitError
from mimickit.util.registry import Entry, Registry
from mimickit.util.warn import warn

if TYPE_CHECKING:
    import mujoco

# Rate bounds: a typo such as sim_freq 3e7 would make one env step run millions of physics steps.
MAX_SIM_FREQ = 10_000
MAX_CONTROL_FREQ = 1_000
MAX_SUBSTEPS = 1_000


class ControlMode(IntEnum):
    """How `set_cmd` values drive the joints (the reference's modes and numbers)."""

    none = 0  # no actuation
    pos = 1  # implicit PD toward position targets inside the solver
    vel = 2  # damping toward velocity targets
    torque = 3  # commands are joint torques
    pd_explicit = 4  # PD torques computed by the engine each substep (hinges and ball-joint exp-maps)


# Names accepted in yaml besides the member names ("pd_1d" is what the project brief calls pd_explicit).
_CONTROL_MODE_ALIASES = {"pd_1d": ControlMode.pd_explicit}


class EngineConfig(ConfigModel):
    """The `engine:` yaml block. Fields after `ground_contact_height` are MuJoCo-only tuning knobs."""

    engine_name: str
    """Which physics backend: "mujoco" (CPU) or "newton" (GPU)."""
    control_mode: ControlMode = ControlMode.none
    """none / pos / vel / torque / pd_explicit (alias pd_1d); an integer 0-4 is accepted too."""
    control_freq: int = Field(10, le=MAX_CONTROL_FREQ)
    """Policy rate in Hz; one `step()` lasts 1 / control_freq seconds."""
    sim_freq: int = Field(60, le=MAX_SIM_FREQ)
    """Physics rate in Hz; a multiple of control_freq, at most MAX_SUBSTEPS times it."""
    env_spacing: float = Field(ge=0)
    """Grid spacing (m) between envs in the reference's viewer (kept so that its yamls load); the envs do not
    share a world, and the studio draws one env at a time."""
    ball_joint_limits: Literal["cone", "none"] = "cone"
    """How 3-D (ball) joints are limited. "cone": the joint's total rotation angle stays below the largest
    |bound| of its three hinge ranges (so no single-axis motion the MJCF allows is cut): the only ball-joint
    limit MuJoCo has, used by both engines (Newton's SolverMuJoCo builds a MuJoCo model) so that they agree.
    PhysX-style per-axis box limits are not expressible as a MuJoCo constraint. "none": unlimited, as
    Newton's MJCF import leaves them. Either way the per-axis ranges bound the actions
    (`get_obj_dof_limits`). Measured on the 23 humanoid reference clips (2,926 frames): 164 frames in 14
    clips have a ball joint past its cone, worst neck 1.39 rad vs 1.05 (dance_a, punch 1.35), right ankle
    1.16 vs 0.96 (sideflip), abdomen 1.62 vs 1.57 (double_kong), right hip 2.53 vs 2.44 (backflip); over
    all 215 clips incl. long/ and parc/ 784 of 63,712 frames, worst abdomen 1.80 (parc climb00). A reset to
    such a frame starts inside the limit constraint, which pushes the joint back (dance_a's neck at 1.39 rad:
    at 1.05 within 3 control steps, tracking the clip in pos mode). The shipped walk clip stays inside."""
    ground_contact_height: float = 0.3
    """Isaac Gym's height threshold for "ground" contacts; MuJoCo reports true floor contacts instead."""
    integrator: Literal["implicitfast", "implicit", "euler", "rk4"] = "implicitfast"
    """MuJoCo integrator; implicitfast treats the PD damping implicitly."""
    solver_iterations: int = Field(20, le=1000)
    """Maximum Newton-solver iterations per substep (MuJoCo). Measured on the humanoid with random PD
    targets (76,800 substeps at 240 Hz): mean 1.4, max 17, so 20 never binds; caps of 3 or less blow up."""
    ls_iterations: int = Field(50, le=1000)
    """Maximum line-search iterations per solver iteration (MuJoCo)."""
    num_threads: int = Field(0, ge=0, le=1024)
    """Worker threads stepping the envs (MuJoCo); 0 = one per CPU core."""

    @field_validator("engine_name")
    @classmethod
    def _known_engine(cls, v: str) -> str:
        if v not in ENGINES:
            raise ValueError(ENGINES.unknown(v))
        return v

    @field_validator("control_mode", mode="before")
    @classmethod
    def _parse_control_mode(cls, v: Any) -> Any:
        if isinstance(v, str):
            key = v.strip().lower()
            if key in _CONTROL_MODE_ALIASES:
                return _CONTROL_MODE_ALIASES[key]
            if key in ControlMode.__members__:
                return ControlMode[key]
            names = ", ".join([*ControlMode.__members__, *_CONTROL_MODE_ALIASES])
            raise ValueError(f"unknown control mode '{v}' (one of: {names})")
        return v

    @field_validator("control_freq", "sim_freq", "solver_iterations", "ls_iterations")
    @classmethod
    def _positive(cls, v: int) -> int:
        if v <= 0:
            raise ValueError("must be a positive integer")
        return v

    @model_validator(mode="after")
    def _sim_multiple_of_control(self) -> EngineConfig:
        if self.sim_freq % self.control_freq != 0:
            raise ValueError(f"sim_freq ({self.sim_freq}) must be a multiple of control_freq ({self.control_freq})")
        if self.substeps > MAX_SUBSTEPS:  # each env step would run that many physics steps
            raise ValueError(
                f"sim_freq / control_freq is {self.substeps} physics steps per control step, over {MAX_SUBSTEPS}"
            )
        return self

    @property
    def substeps(self) -> int:
        """Physics steps per control step."""
        return self.sim_freq // self.control_freq


_NEWTON_EXTRA = (
    "the Newton engine needs the optional extra: pip install .[newton] "
    "(in its own venv, as `make test-newton` builds .venv-newton: newton[sim] pins mujoco 3.17)"
)
ENGINES: Registry[EngineConfig, Engine] = Registry(
    "engine",
    "mimickit.engines.engine:Engine",
    {
        "mujoco": Entry(EngineConfig, "mimickit.engines.mujoco_engine:MujocoEngine"),
        "newton": Entry(EngineConfig, "mimickit.engines.newton_engine:NewtonEngine", missing=_NEWTON_EXTRA),
    },
    not_ported={name: "Isaac Gym / Isaac Lab are not part of this port" for name in ("isaac_gym", "isaac_lab")},
)
"""Every engine by its yaml `engine_name`. Adding an engine: subclass `Engine` in its own module and add
one line here (an engine with fields of its own gets an `EngineConfig` subclass in that line);
`parse_engine_config` and `engine_builder` read this table."""


def parse_engine_config(raw: dict[str, Any], source: str | Path) -> EngineConfig:
    """Validate an engine block against the config class of its `engine_name` (errors name `source`)."""
    name = raw.get("engine_name")
    config_cls = ENGINES.config_class(name) if name in ENGINES else EngineConfig  # which refuses the name
    return parse_config(config_cls, raw, source)


EnvIds = torch.Tensor | np.ndarray | list[int] | None
"""Env indices (LongTensor / int array / list) or None for all envs."""


@dataclass(frozen=True)
class ViewObject:
    """One object of a `MujocoView`, at its obj_id."""

    name: str
    """The name given to `create_obj`."""
    is_visual: bool
    """Drawn only (a reference "ghost", a marker): no collisions."""
    body_ids: np.ndarray
    """[B] MuJoCo body ids of its bodies in the kinematic model's DFS order (the root first)."""


@dataclass(frozen=True)
class MujocoView:
    """What a viewer (the studio, `mimickit video`) draws one env from, for every engine: a compiled MuJoCo
    model of the scene, the env's MjData with its current state (qpos, qvel, and the body poses of
    `mj_kinematics`), and where each object's bodies are in that model, by obj_id."""

    model: mujoco.MjModel
    data: mujoco.MjData
    objects: tuple[ViewObject, ...]


@dataclass
class BodyForce:
    """An external wrench on one body of one env, held for whole control steps (`Engine.apply_body_force`)."""

    env_id: int
    obj_id: int
    body_id: int
    """The body's index in the object's kinematic DFS order (0: the root)."""
    force: np.ndarray
    """[3] N, world frame, at the body's centre of mass."""
    torque: np.ndarray
    """[3] N·m, world frame."""
    steps_left: int
    """Control steps it still acts for (the next `step` is one of them)."""


def ball_cone_angle(low: np.ndarray, high: np.ndarray) -> float | None:
    """The cone limit (rad) of a 3-D joint with per-axis bounds low/high [3]: the largest |bound|, so that
    every single-axis rotation the bounds allow stays reachable; None when that is π or more (an exp-map
    angle never exceeds π, so such a cone limits nothing)."""
    angle = float(np.max(np.abs(np.concatenate([low, high]))))
    return angle if angle < math.pi else None


def has_motors(mode: ControlMode, rec: ObjRecord, kin: KinCharModel) -> bool:
    """Whether an object's DoFs get actuators: a control mode, motors not disabled, and DoFs to drive."""
    return mode != ControlMode.none and not rec.disable_motors and kin.get_dof_size() > 0


def mode_gains(mode: ControlMode, kin: KinCharModel, actuated: bool) -> tuple[np.ndarray, np.ndarray]:
    """(kp, kd) [D] as the control mode uses an object's MJCF gains: zero without motors and in torque
    mode, damping only in vel mode, both otherwise."""
    kp, kd = kin.dof_array("kp"), kin.dof_array("kd")
    if not actuated or mode in (ControlMode.torque, ControlMode.none):
        return np.zeros_like(kp), np.zeros_like(kd)
    if mode == ControlMode.vel:
        return np.zeros_like(kp), kd
    return kp, kd


class Engine(abc.ABC):
    """Base class of the physics engines; see the module docstring for shapes and frames."""

    def __init__(self, config: EngineConfig, num_envs: int, device: torch.device | str, visualize: bool = False):
        """`visualize` is taken as the reference's engines take it; no engine draws itself (viewers draw
        from `mujoco_view`)."""
        self._config = config
        self._num_envs = int(num_envs)
        self._device = torch.device(device)
        self._env_objs: list[list[ObjRecord]] = []  # per env, per object
        self._layouts: list[ObjLayout] = []  # per object, where it lives in the built model (initialize_sim)
        self._kin_cache: dict[str, KinCharModel] = {}  # per asset file
        self._sim_time = 0.0
        self._start_poses: list[list[tuple[np.ndarray, np.ndarray]]] = []  # per env, per obj: (pos[3], xyzw[4])
        self._body_forces: dict[tuple[int, int, int], BodyForce] = {}  # (env, obj, body) -> its push

    @property
    def config(self) -> EngineConfig:
        """The validated engine config (read-only by convention)."""
        return self._config

    # ------------------------------------------------------------------ lifecycle
    @abc.abstractmethod
    def get_name(self) -> str: ...

    def create_env(self) -> int:
        """Start the next env; returns its index (0, 1, ... < num_envs)."""
        env_id = len(self._env_objs)
        if env_id >= self._num_envs:
            raise MimicKitError(f"create_env: all {self._num_envs} envs already exist")
        self._env_objs.append([])
        self._start_poses.append([])
        return env_id

    def create_obj(
        self,
        env_id: int,
        obj_type: ObjType,
        asset_file: str,
        name: str,
        is_visual: bool = False,
        enable_self_collisions: bool = True,
        fix_root: bool = False,
        start_pos: np.ndarray | None = None,
        start_rot: np.ndarray | None = None,
        color: np.ndarray | None = None,
        disable_motors: bool = False,
    ) -> int:
        """Add an object (MJCF asset) to env `env_id`; returns its obj_id (creation order within the env).

        start_pos [3] and start_rot [4] (xyzw) default to the origin and identity; color is RGB(A) in [0, 1].
        The engine builds every object in `initialize_sim`.
        """
        path = self._check_new_obj(env_id, asset_file)
        rgb = None if color is None else tuple(float(c) for c in np.asarray(color).ravel())
        rec = ObjRecord(ObjType(obj_type), path, name, is_visual, enable_self_collisions, fix_root, rgb, disable_motors)
        return self._add_obj(env_id, rec, start_pos, start_rot)

    @abc.abstractmethod
    def initialize_sim(self) -> None:
        """Finalize the worlds after all envs and objects are created."""

    @abc.abstractmethod
    def _sim_initialized(self) -> bool:
        """Whether initialize_sim has built the model (no more objects can be added)."""

    # ------------------------------------------------------------------ object bookkeeping (both engines)
    def _check_new_obj(self, env_id: int, asset_file: str) -> str:
        """Validate a `create_obj` call; returns the asset's path. The env resolves configs' `data/...`
        names (its `DataPaths`) before it asks: an engine takes file paths as they are."""
        if self._sim_initialized():
            raise MimicKitError("create_obj: the simulation is already initialized")
        if not 0 <= env_id < len(self._env_objs):
            raise MimicKitError(f"create_obj: env {env_id} was not created (call create_env first)")
        path = str(Path(asset_file).expanduser())
        if not Path(path).is_file():
            raise MimicKitError(f"asset file not found: {path}")
        return path

    def _add_obj(self, env_id: int, rec: ObjRecord, start_pos: np.ndarray | None,
                 start_rot: np.ndarray | None) -> int:  # fmt: skip
        """Store a validated object and its start pose (identity / origin by default); returns its obj_id."""
        pos = np.zeros(3) if start_pos is None else np.asarray(start_pos, dtype=np.float64).reshape(3)
        rot = np.array([0.0, 0.0, 0.0, 1.0]) if start_rot is None else np.asarray(start_rot, np.float64).reshape(4)
        self._env_objs[env_id].append(rec)
        self._start_poses[env_id].append((pos, rot / np.linalg.norm(rot)))
        return len(self._env_objs[env_id]) - 1

    def _check_env_objects(self) -> list[ObjRecord]:
        """Every env created, each with env 0's objects (one model serves all envs); returns env 0's."""
        if len(self._env_objs) != self._num_envs:
            raise MimicKitError(f"initialize_sim: {len(self._env_objs)} of {self._num_envs} envs were created")
        objs = self._env_objs[0]
        for e, env_objs in enumerate(self._env_objs):
            if [o.signature() for o in env_objs] != [o.signature() for o in objs]:
                raise MimicKitError(
                    f"env {e} has different objects than env 0; the {self.get_name()} engine needs identical "
                    "object lists"
                )
        return objs

    def _kin_model(self, asset_file: str) -> KinCharModel:
        """The kinematic model of an asset, loaded once per file."""
        if asset_file not in self._kin_cache:
            self._kin_cache[asset_file] = load_char_model(asset_file)
        return self._kin_cache[asset_file]

    def _warn_explicit_damping(self, kin: KinCharModel, kd: np.ndarray, inertia: np.ndarray) -> None:
        """pd_explicit applies the damping explicitly: a DoF of effective inertia M (mass-matrix diagonal with
        armature, [D] `inertia`) diverges once kd·dt / M ≥ 2, where pos mode's implicit damping does not.
        Measured on the humanoid: the ankles reach 14.6 at 240 Hz and fall; 1920 Hz (1.8) holds the pose."""
        ratio = kd * self.get_sim_timestep() / np.maximum(inertia, 1e-12)
        worst = int(np.argmax(ratio)) if len(ratio) else -1
        if worst < 0 or ratio[worst] < 2.0:
            return
        stable_freq = math.ceil(self._config.sim_freq * ratio[worst] / 2.0)
        joint = kin.joints[1 + int(kin.dof_joint_ids()[worst])]
        dof = f"{joint.name}[{worst - joint.dof_idx}]" if joint.dof_dim > 1 else joint.name
        warn(
            f"control_mode pd_explicit: the explicit PD damping diverges at sim_freq {self._config.sim_freq} Hz "
            f"on '{kin.source}' (kd·dt/M = {ratio[worst]:.1f} at DoF {dof}, stable below 2); use a "
            f"sim_freq above {stable_freq} Hz or control_mode pos",
            stacklevel=4,  # the caller of initialize_sim
        )

    def _ball_cone(self, low: np.ndarray, high: np.ndarray) -> float | None:
        """The cone limit (rad) to enforce on a ball joint with per-axis bounds low/high [3], None for none."""
        return ball_cone_angle(low, high) if self._config.ball_joint_limits == "cone" else None

    @abc.abstractmethod
    def set_cmd(self, obj_id: int, cmd: torch.Tensor) -> None:
        """Store the command [N, D] for the control mode (pos targets, vel targets or torques)."""

    def step(self) -> None:
        """Advance one control step (all substeps, all envs) and refresh the state tensors."""
        with self.stepping():
            pass

    @abc.abstractmethod
    def stepping(self) -> AbstractContextManager[None]:
        """A control step (as `step`) while the block runs on the calling thread: for a caller's work that
        neither reads nor writes this engine, which may then overlap the physics (the MuJoCo engine's
        worker threads step the envs meanwhile; Newton's kernels are queued before it). An engine that
        cannot overlap runs the block, then the step."""

    # ------------------------------------------------------------------ external forces (a push)
    def apply_body_force(
        self,
        env_id: int,
        obj_id: int,
        body_id: int,
        force: np.ndarray | list[float],
        torque: np.ndarray | list[float] | None = None,
        duration_s: float = 0.2,
    ) -> int:
        """Push body `body_id` (kinematic DFS order) of object `obj_id` in env `env_id` with `force` [3] N
        (and `torque` [3] N·m), world frame at its centre of mass, over the next control steps: the
        duration rounded to whole control steps, at least one (a step's substeps run in one call).
        Returns the steps. A new push on the same body replaces the old one; setting the object's root
        position (a reset places it anew) ends its pushes. MimicKitError for what cannot be pushed."""
        self._check_body_force(env_id, obj_id, body_id)
        f = np.asarray(force, dtype=np.float64).reshape(-1)
        t = np.zeros(3) if torque is None else np.asarray(torque, dtype=np.float64).reshape(-1)
        if f.shape != (3,) or t.shape != (3,) or not (np.isfinite(f).all() and np.isfinite(t).all()):
            raise MimicKitError("apply_body_force: force and torque must be 3 finite numbers each")
        if not (math.isfinite(duration_s) and duration_s > 0):
            raise MimicKitError(f"apply_body_force: duration_s must be a positive number of seconds, not {duration_s}")
        steps = max(1, round(duration_s / self.get_timestep()))
        self._body_forces[(int(env_id), int(obj_id), int(body_id))] = BodyForce(
            int(env_id), int(obj_id), int(body_id), f, t, steps
        )
        self._body_forces_changed()
        return steps

    def get_body_forces(self, env_id: int | None = None) -> list[BodyForce]:
        """The pushes that act on the next control step (of env `env_id`, or all), copies."""
        return [
            BodyForce(f.env_id, f.obj_id, f.body_id, f.force.copy(), f.torque.copy(), f.steps_left)
            for f in self._body_forces.values()
            if env_id is None or f.env_id == env_id
        ]

    def _check_body_force(self, env_id: int, obj_id: int, body_id: int) -> None:
        if not self._sim_initialized():
            raise MimicKitError("apply_body_force: the simulation is not initialized yet")
        if not 0 <= int(env_id) < self._num_envs:
            raise MimicKitError(f"apply_body_force: env {env_id} is out of range (the engine has {self._num_envs})")
        if not 0 <= int(obj_id) < len(self._layouts):
            raise MimicKitError(f"apply_body_force: no object {obj_id} (each env has {len(self._layouts)})")
        if self._env_objs[int(env_id)][int(obj_id)].is_visual:
            raise MimicKitError(f"apply_body_force: object {obj_id} is visual only; nothing pushes it")
        bodies = self.get_obj_num_bodies(int(obj_id))
        if not 0 <= int(body_id) < bodies:
            raise MimicKitError(f"apply_body_force: object {obj_id} has {bodies} bodies, not body {body_id}")

    def _count_body_force_step(self) -> None:
        """After a control step: each push has one step fewer; those done are dropped."""
        if not self._body_forces:
            return
        for key, f in list(self._body_forces.items()):
            f.steps_left -= 1
            if f.steps_left <= 0:
                del self._body_forces[key]
        self._body_forces_changed()

    def _end_body_forces(self, env_ids: np.ndarray | torch.Tensor, obj_id: int) -> None:
        """Object `obj_id` placed anew in envs `env_ids` (a reset): its pushes end there."""
        if not self._body_forces:
            return
        ids = {int(i) for i in np.asarray(env_ids.cpu() if isinstance(env_ids, torch.Tensor) else env_ids).ravel()}
        ended = [k for k in self._body_forces if k[1] == obj_id and k[0] in ids]
        for k in ended:
            del self._body_forces[k]
        if ended:
            self._body_forces_changed()

    def _body_forces_changed(self) -> None:
        """The set of pushes changed: an engine that keeps them in its own arrays between steps (MuJoCo's
        `xfrc_applied`) rewrites them; one that writes them before each substep has nothing to do."""
        return None

    # ------------------------------------------------------------------ timing / misc
    def get_timestep(self) -> float:
        """Control timestep dt = 1 / control_freq (s)."""
        return 1.0 / self._config.control_freq

    def get_sim_timestep(self) -> float:
        """Physics timestep = 1 / sim_freq (s)."""
        return 1.0 / self._config.sim_freq

    def get_num_envs(self) -> int:
        return self._num_envs

    def get_control_mode(self) -> ControlMode:
        return self._config.control_mode

    def get_sim_time(self) -> float:
        """Simulated seconds since initialize_sim."""
        return self._sim_time

    @abc.abstractmethod
    def get_gravity(self) -> np.ndarray:
        """Gravity vector (3,)."""

    def get_objs_per_env(self) -> int:
        return len(self._env_objs[0]) if self._env_objs else 0

    # ------------------------------------------------------------------ what viewers and the bench read
    @abc.abstractmethod
    def mujoco_view(self, env_id: int = 0) -> MujocoView:
        """Env `env_id` as a MuJoCo model and MjData to draw, with every setter edit applied. The model is
        the same on every call; the data holds the state at the time of the call (call again after a step
        or a setter). Read it, never step it: it may be the engine's own."""

    def close(self) -> None:
        """Release what the engine holds besides memory (the MuJoCo engine's worker threads); nothing here."""
        return None

    def _check_view_env(self, env_id: int) -> int:
        if not self._sim_initialized():
            raise MimicKitError("mujoco_view: the simulation is not initialized yet")
        if not 0 <= int(env_id) < self._num_envs:
            raise MimicKitError(f"mujoco_view: env {env_id} is out of range (the engine has {self._num_envs} envs)")
        return int(env_id)

    # ------------------------------------------------------------------ state getters (live [N, ...] views)
    @abc.abstractmethod
    def _state_tensor(self, obj_id: int, name: str) -> torch.Tensor:
        """Object `obj_id`'s live getter tensor `name` (`engine_records.state_shapes`), with pending setter
        edits applied."""

    def get_root_pos(self, obj_id: int) -> torch.Tensor:
        """[N, 3] root origin position (env-local)."""
        return self._state_tensor(obj_id, "root_pos")

    def get_root_rot(self, obj_id: int) -> torch.Tensor:
        """[N, 4] root orientation, xyzw."""
        return self._state_tensor(obj_id, "root_rot")

    def get_root_vel(self, obj_id: int) -> torch.Tensor:
        """[N, 3] root centre-of-mass linear velocity, world frame."""
        return self._state_tensor(obj_id, "root_vel")

    def get_root_ang_vel(self, obj_id: int) -> torch.Tensor:
        """[N, 3] root angular velocity, world frame."""
        return self._state_tensor(obj_id, "root_ang_vel")

    def get_dof_pos(self, obj_id: int) -> torch.Tensor:
        """[N, D] joint coordinates (hinge angles, spherical exp-maps)."""
        return self._state_tensor(obj_id, "dof_pos")

    def get_dof_vel(self, obj_id: int) -> torch.Tensor:
        """[N, D] joint velocities (spherical: local angular velocity)."""
        return self._state_tensor(obj_id, "dof_vel")

    def get_joint_rot(self, obj_id: int) -> torch.Tensor:
        """[N, J-1, 4] each joint's local rotation, xyzw (identity for fixed joints): the DoFs as the
        kinematic model's `dof_to_rot` turns them into rotations. An engine that stores rotations
        (MuJoCo's ball joints are quaternions) overrides it to skip the exp-map round trip."""
        return self._obj_kin(obj_id).dof_to_rot(self.get_dof_pos(obj_id))

    @abc.abstractmethod
    def get_dof_forces(self, obj_id: int) -> torch.Tensor:
        """[N, D] actuator forces of the last substep."""

    def get_body_pos(self, obj_id: int) -> torch.Tensor:
        """[N, B, 3] body origin positions."""
        return self._state_tensor(obj_id, "body_pos")

    def get_body_rot(self, obj_id: int) -> torch.Tensor:
        """[N, B, 4] body orientations, xyzw."""
        return self._state_tensor(obj_id, "body_rot")

    def get_body_vel(self, obj_id: int) -> torch.Tensor:
        """[N, B, 3] body centre-of-mass linear velocities, world frame."""
        return self._state_tensor(obj_id, "body_vel")

    def get_body_ang_vel(self, obj_id: int) -> torch.Tensor:
        """[N, B, 3] body angular velocities, world frame."""
        return self._state_tensor(obj_id, "body_ang_vel")

    def get_contact_forces(self, obj_id: int) -> torch.Tensor:
        """[N, B, 3] total contact force acting on each body, world frame."""
        return self._state_tensor(obj_id, "contact_forces")

    def get_ground_contact_forces(self, obj_id: int) -> torch.Tensor:
        """[N, B, 3] contact force from the ground acting on each body, world frame."""
        return self._state_tensor(obj_id, "ground_contact_forces")

    # ------------------------------------------------------------------ state setters
    @abc.abstractmethod
    def set_root_pos(self, env_ids: EnvIds, obj_id: int, root_pos: torch.Tensor | float) -> None:
        """root_pos broadcastable to [n, 3]."""

    @abc.abstractmethod
    def set_root_rot(self, env_ids: EnvIds, obj_id: int, root_rot: torch.Tensor | float) -> None:
        """root_rot broadcastable to [n, 4], xyzw."""

    @abc.abstractmethod
    def set_root_vel(self, env_ids: EnvIds, obj_id: int, root_vel: torch.Tensor | float) -> None:
        """root_vel broadcastable to [n, 3]: centre-of-mass velocity, world frame."""

    @abc.abstractmethod
    def set_root_ang_vel(self, env_ids: EnvIds, obj_id: int, root_ang_vel: torch.Tensor | float) -> None:
        """root_ang_vel broadcastable to [n, 3], world frame."""

    def set_root_state(
        self,
        env_ids: EnvIds,
        obj_id: int,
        root_pos: torch.Tensor | float,
        root_rot: torch.Tensor | float,
        root_vel: torch.Tensor | float,
        root_ang_vel: torch.Tensor | float,
    ) -> None:
        """The four root setters in one call: what a reset does. An engine that stores velocities in
        another frame overrides it to convert once instead of once per setter."""
        self.set_root_pos(env_ids, obj_id, root_pos)
        self.set_root_rot(env_ids, obj_id, root_rot)
        self.set_root_vel(env_ids, obj_id, root_vel)
        self.set_root_ang_vel(env_ids, obj_id, root_ang_vel)

    @abc.abstractmethod
    def set_dof_pos(self, env_ids: EnvIds, obj_id: int, dof_pos: torch.Tensor | float) -> None:
        """dof_pos broadcastable to [n, D]."""

    @abc.abstractmethod
    def set_dof_vel(self, env_ids: EnvIds, obj_id: int, dof_vel: torch.Tensor | float) -> None:
        """dof_vel broadcastable to [n, D]."""

    def set_joint_rot(self, env_ids: EnvIds, obj_id: int, joint_rot: torch.Tensor) -> None:
        """Set the DoFs from local joint rotations [n, J-1, 4] (xyzw), as `set_dof_pos` of the model's
        `rot_to_dof`: what a reset to a clip frame does."""
        self.set_dof_pos(env_ids, obj_id, self._obj_kin(obj_id).rot_to_dof(joint_rot))

    def _obj_kin(self, obj_id: int) -> KinCharModel:
        """The kinematic model of object `obj_id` (its joints and DoF layout)."""
        return self._layouts[obj_id].kin

    # ------------------------------------------------------------------ model queries
    def get_obj_num_dofs(self, obj_id: int) -> int:
        return self._layouts[obj_id].num_dofs

    def get_obj_num_bodies(self, obj_id: int) -> int:
        return self._layouts[obj_id].num_bodies

    def get_obj_body_names(self, obj_id: int) -> list[str]:
        """Body names in the kinematic model's DFS order."""
        return self._obj_kin(obj_id).get_body_names()

    def find_obj_body_id(self, obj_id: int, name: str) -> int:
        return self._obj_kin(obj_id).get_body_id(name)

    def get_obj_torque_limits(self, env_id: int, obj_id: int) -> np.ndarray:
        """[D] torque limits."""
        return self._obj_kin(obj_id).dof_array("torque_limit")

    def get_obj_dof_limits(self, env_id: int, obj_id: int) -> tuple[np.ndarray, np.ndarray]:
        """(low [D], high [D]) per-DoF position limits (action bounds)."""
        low, high = self._obj_kin(obj_id).dof_limits()
        return low.copy(), high.copy()

    def get_obj_pd_gains(self, env_id: int, obj_id: int) -> tuple[np.ndarray, np.ndarray]:
        """(kp [D], kd [D]) as used by the control mode."""
        lay = self._layouts[obj_id]
        return lay.kp.copy(), lay.kd.copy()

    @abc.abstractmethod
    def calc_obj_mass(self, env_id: int, obj_id: int) -> float: ...
