"""Build an environment from an env yaml and an engine yaml, choosing the class by `env_name`."""

from __future__ import annotations

from pathlib import Path

import torch

from mimickit.engines.engine import EngineConfig
from mimickit.envs.env_config import CharEnvConfig, load_env_configs
from mimickit.envs.sim_env import SimEnv


def build_env(
    env_file: str | Path,
    engine_file: str | Path | None,
    num_envs: int,
    device: torch.device | str = "cpu",
    visualize: bool = False,
) -> SimEnv:
    env_cfg, engine_cfg = load_env_configs(env_file, engine_file)
    return build_env_from_configs(env_cfg, engine_cfg, num_envs, device, visualize)


def build_env_from_configs(
    env_cfg: CharEnvConfig,
    engine_cfg: EngineConfig,
    num_envs: int,
    device: torch.device | str = "cpu",
    visualize: bool = False,
) -> SimEnv:
    """The env class named by `env_cfg.env_name` on validated configs (callers that edit them, e.g. sim2sim)."""
    if env_cfg.env_name == "char":
        from mimickit.envs.char_env import CharEnv as cls
    elif env_cfg.env_name == "deepmimic":
        from mimickit.envs.deepmimic_env import DeepMimicEnv as cls
    elif env_cfg.env_name == "amp":
        from mimickit.envs.amp_env import AMPEnv as cls
    elif env_cfg.env_name == "ase":
        from mimickit.envs.ase_env import ASEEnv as cls
    elif env_cfg.env_name == "add":
        from mimickit.envs.add_env import ADDEnv as cls
    elif env_cfg.env_name == "task_location":
        from mimickit.envs.task_location_env import TaskLocationEnv as cls
    elif env_cfg.env_name == "task_steering":
        from mimickit.envs.task_steering_env import TaskSteeringEnv as cls
    elif env_cfg.env_name == "view_motion":
        from mimickit.envs.view_motion_env import ViewMotionEnv as cls
    elif env_cfg.env_name == "char_dof_test":
        from mimickit.envs.char_dof_test_env import CharDofTestEnv as cls
    else:  # load_env_configs already refused other names
        raise AssertionError(env_cfg.env_name)
    return cls(env_cfg, engine_cfg, num_envs, device, visualize)
