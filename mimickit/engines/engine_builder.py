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
        try:
            from mimickit.engines.newton_engine import NewtonEngine
        except ImportError as exc:  # the optional extra is missing (or broken): say how to install it
            raise MimicKitError(
                f"{source}: the Newton engine needs the optional extra: pip install .[newton] "
                f"(in its own venv, as `make test-newton` builds .venv-newton: newton[sim] pins mujoco 3.17); "
                f"import failed: {exc}"
            ) from exc

        return NewtonEngine(config, num_envs, device, visualize)
    raise MimicKitError(f"{source}: unknown engine '{config.engine_name}'")  # unreachable: the config checks it
