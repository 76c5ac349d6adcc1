"""Build the engine named by an engine config (the yaml `engine:` block, spec §2.1)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from mimickit.engines.engine import Engine, EngineConfig
from mimickit.util.config import parse_config
from mimickit.util.errors import MimicKitError


def build_engine(
    config: EngineConfig | dict[str, Any],
    num_envs: int,
    device: torch.device | str,
    visualize: bool = False,
    source: str | Path = "engine config",
) -> Engine:
    """An engine for `num_envs` envs on `device`; a dict config is validated first (errors name `source`)."""
    if not isinstance(config, EngineConfig):
        config = parse_config(EngineConfig, dict(config), source)
    if config.engine_name == "mujoco":
        from mimickit.engines.mujoco_engine import MujocoEngine

        return MujocoEngine(config, num_envs, device, visualize)
    if config.engine_name == "newton":
        raise MimicKitError(
            "the Newton engine is not built yet; when it is, it will need the optional extra: pip install .[newton]"
        )
    raise MimicKitError(f"{source}: unknown engine '{config.engine_name}'")  # unreachable: the config checks it
