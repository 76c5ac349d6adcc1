"""Typed configs of the environments, and loading an env yaml (+ engine yaml) the reference's way.

An env yaml is `env_name: ...`, the env's fields (under `env:` as in MimicKit's files, or at the top
level), and an optional `engine:` block whose entries override the engine config (as the reference's env builder does).

Adding an env: write its config class here and its env class in its own module, then add one line to
`ENVS` below the config classes (name → config class, "module:Class"). `load_env_configs` and
`env_builder` read that table; nothing else names envs.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

from pydantic import Field, model_validator

from mimickit.engines.engine import EngineConfig, parse_engine_config
from mimickit.util.config import ConfigModel, load_yaml, parse_config
from mimickit.util.errors import MimicKitError
from mimickit.util.registry import Entry, Registry
from mimickit.util.warn import warn

if TYPE_CHECKING:
    from mimickit.envs.sim_env import SimEnv

# Engine keys that only Isaac Gym / Isaac Lab read; MimicKit env yamls may carry them.
_ISAAC_ONLY_KEYS = {"sim", "plane", "physx"}
# Keys that describe the task rather than one engine's physics: kept when an env yaml's engine block
# names another engine than the one chosen.
_PORTABLE_ENGINE_KEYS = {"control_mode", "control_freq", "env_spacing", "ground_contact_height", "ball_joint_limits"}


# Bounds on numbers that size a buffer or a loop: one mistyped value must not mean a giant allocation.
MAX_PHASE_ENCODING = 16  # frequencies 2^k: past 2^16 they are beyond a float32 phase's resolution
MAX_TAR_OBS_STEPS = 64
MAX_TAR_OBS_STEP = 1_000
MAX_DISC_OBS_STEPS = 256


class SimEnvConfig(ConfigModel):
    env_name: str
    episode_length: float = Field(gt=0, description="seconds per episode")
    """Seconds per episode, finite."""


class CharEnvConfig(SimEnvConfig):
    char_file: str
    global_obs: bool
    root_height_obs: bool = True
    zero_center_action: bool = False
    init_pose: list[float] | None = Field(None, max_length=1_000)
    key_bodies: list[str] = Field([], max_length=1_000)
    camera_mode: str = "still"


class DeepMimicEnvConfig(CharEnvConfig):
    motion_file: str
    enable_early_termination: bool
    ref_char_offset: list[float] = Field(min_length=3, max_length=3)
    num_phase_encoding: int = Field(0, ge=0, le=MAX_PHASE_ENCODING)
    """Sin/cos pairs of the phase at frequencies 2π·2^k, k < num_phase_encoding."""
    pose_termination: bool = False
    pose_termination_dist: float = Field(1.0, gt=0)
    enable_phase_obs: bool = True
    enable_tar_obs: bool = False
    tar_obs_steps: list[Annotated[int, Field(ge=1, le=MAX_TAR_OBS_STEP)]] = Field(
        [1], min_length=1, max_length=MAX_TAR_OBS_STEPS
    )
    """Control steps ahead at which the target observation shows the reference (each >= 1)."""
    rand_reset: bool = True
    log_tracking_error: bool = False
    visualize_ref_char: bool = True
    contact_bodies: list[str] = Field([], max_length=1_000)
    joint_err_w: list[float] | None = Field(None, max_length=1_000)
    reward_pose_w: float
    reward_vel_w: float
    reward_root_pose_w: float
    reward_root_vel_w: float
    reward_key_pos_w: float
    reward_pose_scale: float
    reward_vel_scale: float
    reward_root_pose_scale: float
    reward_root_vel_scale: float
    reward_key_pos_scale: float

    @model_validator(mode="after")
    def _key_bodies_needed(self) -> DeepMimicEnvConfig:
        if not self.key_bodies:
            raise ValueError("key_bodies must name at least one body (the key-position reward needs it)")
        return self


class AMPEnvConfig(DeepMimicEnvConfig):
    num_disc_obs_steps: int = Field(ge=1, le=MAX_DISC_OBS_STEPS)
    """Steps of state history in one discriminator observation (humanoid: 10)."""
    disc_dof_vel_obs: bool = True
    """Include the DoF velocities in the discriminator observation."""


class ADDEnvConfig(AMPEnvConfig):
    """AMP's fields; ADD's disc obs hold every body and the reference is tracked as in DeepMimic
    (humanoid: num_disc_obs_steps 1, log_tracking_error True)."""


class TaskLocationEnvConfig(AMPEnvConfig):
    """AMP + walk to a target location on the ground (humanoid yaml: speed 1, change 5–10 s, dist ≤ 10)."""

    tar_speed: float = Field(gt=0, description="m/s the velocity reward asks for towards the target")
    tar_change_time_min: float = Field(gt=0, description="s")
    tar_change_time_max: float = Field(gt=0, description="s")
    tar_dist_max: float = Field(gt=0, description="m from the root")
    tar_dist_min: float = Field(0.0, ge=0)
    dist_threshold: float = Field(0.5, description="squared xy distance (m²) that counts as at the target")
    pos_err_scale: float = 0.5
    vel_err_scale: float = 4.0
    pos_reward_w: float = 0.5
    vel_reward_w: float = 0.4
    face_reward_w: float = 0.1


class TaskSteeringEnvConfig(AMPEnvConfig):
    """AMP + move in a commanded direction at a commanded speed, optionally facing another way."""

    rand_tar_dir: bool = True
    rand_face_dir: bool = True
    tar_speed_min: float = Field(ge=0, description="m/s")
    tar_speed_max: float = Field(ge=0, description="m/s")
    tar_change_time_min: float = Field(gt=0, description="s")
    tar_change_time_max: float = Field(gt=0, description="s")
    reward_steering_tar_w: float
    reward_steering_face_w: float
    reward_steering_vel_scale: float


class ASEEnvConfig(AMPEnvConfig):
    """AMP's fields plus the chance of starting an episode from the default pose."""

    default_reset_prob: float = Field(ge=0, le=1)
    """Per reset env, the probability of the init pose (zero velocities) instead of a clip state."""


class ViewMotionEnvConfig(CharEnvConfig):
    motion_file: str
    global_obs: bool = False


class CharDofTestEnvConfig(CharEnvConfig):
    global_obs: bool = False


ENVS: Registry[CharEnvConfig, SimEnv] = Registry(
    "env",
    "mimickit.envs.sim_env:SimEnv",
    {
        "char": Entry(CharEnvConfig, "mimickit.envs.char_env:CharEnv"),
        "deepmimic": Entry(DeepMimicEnvConfig, "mimickit.envs.deepmimic_env:DeepMimicEnv"),
        "amp": Entry(AMPEnvConfig, "mimickit.envs.amp_env:AMPEnv"),
        "add": Entry(ADDEnvConfig, "mimickit.envs.add_env:ADDEnv"),
        "ase": Entry(ASEEnvConfig, "mimickit.envs.ase_env:ASEEnv"),
        "task_location": Entry(TaskLocationEnvConfig, "mimickit.envs.task_location_env:TaskLocationEnv"),
        "task_steering": Entry(TaskSteeringEnvConfig, "mimickit.envs.task_steering_env:TaskSteeringEnv"),
        "view_motion": Entry(ViewMotionEnvConfig, "mimickit.envs.view_motion_env:ViewMotionEnv"),
        "char_dof_test": Entry(CharDofTestEnvConfig, "mimickit.envs.char_dof_test_env:CharDofTestEnv"),
    },
)
"""Every env by its yaml `env_name`: `load_env_configs` and `env_builder` both use this table."""


def load_env_configs(
    env_file: str | Path, engine_file: str | Path | None, motion_file: str | Path | None = None
) -> tuple[CharEnvConfig, EngineConfig]:
    """Read and validate an env yaml and an engine yaml (the env's `engine:` block merged in);
    `motion_file` (`--motion_file`) replaces the env's clip or dataset."""
    raw = load_yaml(env_file)
    env_name = raw.get("env_name")
    if env_name is None:
        raise MimicKitError(f"{env_file}: missing required key 'env_name'")
    if env_name not in ENVS:
        raise MimicKitError(f"{env_file}: key 'env_name': {ENVS.unknown(env_name)}")
    fields = (
        dict(raw["env"])
        if isinstance(raw.get("env"), dict)
        else {k: v for k, v in raw.items() if k not in ("env_name", "engine")}
    )
    fields["env_name"] = env_name
    env_cfg = parse_config(ENVS.config_class(env_name), fields, env_file)
    if motion_file is not None:
        if not hasattr(env_cfg, "motion_file"):
            raise MimicKitError(f"--motion_file: env {env_name!r} ({env_file}) has no motion_file to replace")
        env_cfg = env_cfg.model_copy(update={"motion_file": str(motion_file)})
    engine_raw = load_yaml(engine_file) if engine_file else {}
    engine_raw = merge_engine_overrides(engine_raw, raw.get("engine") or {}, env_file)
    if not engine_raw:
        raise MimicKitError(f"{env_file}: no engine config given (--engine_config) and no engine: block")
    source = engine_file or env_file
    return env_cfg, parse_engine_config(engine_raw, source)


def merge_engine_overrides(engine: dict[str, Any], override: dict[str, Any], env_file: str | Path) -> dict[str, Any]:
    if not engine:
        return {k: v for k, v in override.items() if k not in _ISAAC_ONLY_KEYS}
    merged = dict(engine)
    other_engine = "engine_name" in override and override["engine_name"] != engine.get("engine_name")
    dropped = []
    for key, val in override.items():
        if key in _ISAAC_ONLY_KEYS or (other_engine and key not in _PORTABLE_ENGINE_KEYS):
            dropped.append(key)
            continue
        merged[key] = val
    if dropped:
        warn(
            f"{env_file}: engine keys {dropped} belong to engine {override.get('engine_name', 'isaac')!r} "
            f"and are ignored for {engine.get('engine_name')!r}",
            stacklevel=2,
        )
    return merged
