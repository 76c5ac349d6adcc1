"""Build the engine named by an engine config (the yaml `engine:` block), the class taken from
the `ENGINES` table in `engine` (where a new engine is registered: one line there, nothing here)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from mimickit.engines.engine import ENGINES, Engine, EngineConfig, parse_engine_config


def build_engine(
    config: EngineConfig | dict[str, Any],
    num_envs: int,
    device: torch.device | str,
    visualize: bool = False,
    source: str | Path = "engine config",
) -> Engine:
    """An engine for `num_envs` envs on `device`; a dict config is validated first (errors name `source`).
    The engine's module is imported only now: one that needs a missing optional extra (Newton) is one
    `MimicKitError` saying how to install it."""
    if not isinstance(config, EngineConfig):
        config = parse_engine_config(dict(config), source)
    return ENGINES.resolve(config.engine_name, str(source))(config, num_envs, device, visualize)
