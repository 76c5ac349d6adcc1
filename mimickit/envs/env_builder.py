"""Build an environment from an env yaml and an engine yaml, choosing the class by `env_name` from the
`ENVS` table in `env_config` (where a new env is registered: one line there, nothing here)."""

from __future__ import annotations

from pathlib import Path

import torch

from mimickit.engines.engine import EngineConfig
from mimickit.envs.env_config import ENVS, CharEnvConfig, load_env_configs
from mimickit.envs.sim_env import SimEnv
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA, DataPaths


def build_env(
    env_file: str | Path,
    engine_file: str | Path | None,
    num_envs: int,
    device: torch.device | str = "cpu",
    visualize: bool = False,
    data_paths: DataPaths = PROJECT_DATA,
    motion_file: str | Path | None = None,
) -> SimEnv:
    """The env of an env yaml and an engine yaml, `motion_file` (when given) replacing the env's clip or
    dataset; the configs' `data/...` files are found by `data_paths`."""
    env_cfg, engine_cfg = load_env_configs(env_file, engine_file, motion_file)
    return build_env_from_configs(env_cfg, engine_cfg, num_envs, device, visualize, data_paths)


def build_env_from_configs(
    env_cfg: CharEnvConfig,
    engine_cfg: EngineConfig,
    num_envs: int,
    device: torch.device | str = "cpu",
    visualize: bool = False,
    data_paths: DataPaths = PROJECT_DATA,
) -> SimEnv:
    """The env class registered for `env_cfg.env_name` (`ENVS`), imported only now, on validated configs
    (callers that edit them, e.g. sim2sim)."""
    if env_cfg.env_name not in ENVS:  # a config built in code; load_env_configs refuses these itself
        raise MimicKitError(f"env config: key 'env_name': {ENVS.unknown(env_cfg.env_name)}")
    return ENVS.resolve(env_cfg.env_name)(env_cfg, engine_cfg, num_envs, device, visualize, data_paths)
