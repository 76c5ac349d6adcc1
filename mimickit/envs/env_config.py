"""Typed configs of the environments (the reference's env yaml fields and defaults).

Adding an env: write its config class here and its env class in its own module, then add one line to
`ENVS` in `env_builder` (name → config class, "module:Class"), which loads the yamls; nothing else names
envs. This module imports no env: the envs import their configs from it.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import Field, model_validator

from mimickit.envs.deepmimic_rewards import DeepMimicRewardConfig
from mimickit.util.config import ConfigModel

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


class DeepMimicEnvConfig(CharEnvConfig, DeepMimicRewardConfig):
    """The reward's weights and scales are `DeepMimicRewardConfig`'s (`deepmimic_rewards.py`, beside the terms)."""

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

    @model_validator(mode="after")
    def _key_bodies_needed(self) -> DeepMimicEnvConfig:
        if not self.key_bodies:
            raise ValueError("key_bodies must name at least one body (the key-position reward needs it)")
        return self


MAX_STATIC_OBJECTS = 64


class StaticObjectConfig(ConfigModel):
    """One fixed object of the `static_objects` env: an MJCF asset at `pos` (m) turned by `rot` (xyzw)."""

    file: str
    pos: list[float] = Field(min_length=3, max_length=3)
    rot: list[float] = Field([0.0, 0.0, 0.0, 1.0], min_length=4, max_length=4)

    @model_validator(mode="after")
    def _unit_rotation(self) -> StaticObjectConfig:
        if abs(sum(c * c for c in self.rot) ** 0.5 - 1.0) > 1e-3:
            raise ValueError(f"rot {self.rot} is not a unit quaternion (x, y, z, w)")
        return self


class StaticObjectsEnvConfig(DeepMimicEnvConfig):
    """DeepMimic with objects fixed in the world that the character collides with (vaults, boxes)."""

    objects: list[StaticObjectConfig] = Field(min_length=1, max_length=MAX_STATIC_OBJECTS)


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


class SMPEnvConfig(AMPEnvConfig):
    """AMP's fields: SMP changes the agent (a motion prior's reward) and, with GSI, where resets start."""


MAX_PROJECTILES = 16


class TaskDodgeballEnvConfig(SMPEnvConfig):
    """SMP + dodge balls thrown at `proj_target_body` (the reference's `task_dodgeball` fields and defaults).

    Each projectile is launched when its trigger time comes (U[proj_trigger_time_min, max] s after the
    previous launch or the reset) from proj_dist m away (xy) at height proj_h m and speed proj_speed m/s."""

    proj_target_body: str
    num_projectiles: int = Field(1, ge=1, le=MAX_PROJECTILES)
    hit_dist: float = Field(0.8, gt=0, description="m: a ball this close to a body may count as a hit")
    hit_force_threshold: float = Field(0.1, ge=0, description="N: xy contact force on a ball that counts as a hit")
    hit_delta_v_threshold: float = Field(1.5, ge=0, description="m/s: a ball's velocity change beyond gravity's")
    proj_dist_min: float = Field(8.0, gt=0, description="m")
    proj_dist_max: float = Field(10.0, gt=0, description="m")
    proj_h_min: float = Field(0.5, ge=0, description="m; at least the ball's radius (0.1)")
    proj_h_max: float = Field(2.5, ge=0, description="m")
    proj_speed_min: float = Field(12.0, gt=0, description="m/s")
    proj_speed_max: float = Field(15.0, gt=0, description="m/s")
    proj_trigger_time_min: float = Field(1.0, ge=0, description="s")
    proj_trigger_time_max: float = Field(4.0, ge=0, description="s")
    proj_aim_noise_scale: float = Field(0.1, ge=0, description="m: std of the aim point's Gaussian noise")

    @model_validator(mode="after")
    def _ranges_ordered(self) -> TaskDodgeballEnvConfig:
        for name in ("proj_dist", "proj_h", "proj_speed", "proj_trigger_time"):
            lo, hi = getattr(self, f"{name}_min"), getattr(self, f"{name}_max")
            if lo > hi:
                raise ValueError(f"{name}_min {lo} > {name}_max {hi}")
        return self


class ASEEnvConfig(AMPEnvConfig):
    """AMP's fields plus the chance of starting an episode from the default pose."""

    default_reset_prob: float = Field(ge=0, le=1)
    """Per reset env, the probability of the init pose (zero velocities) instead of a clip state."""


class ViewMotionEnvConfig(CharEnvConfig):
    motion_file: str
    global_obs: bool = False


class CharDofTestEnvConfig(CharEnvConfig):
    global_obs: bool = False
