"""Load an env yaml and an engine yaml the reference's way and build the env, choosing the class by
`env_name` from the `ENVS` table below (where a new env is registered: its config class from `env_config`
and its "module:Class", one line; nothing else names envs).

An env yaml is `env_name: ...`, the env's fields (under `env:` as in MimicKit's files, or at the top
level), and an optional `engine:` block whose entries override the engine config (as the reference's env builder does).
Beside an `env:` block only `env_name` and `engine` may stand: any other key there is an error, as an
unknown key inside the block is (a clip named beside the block would otherwise be silently ignored).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from mimickit.engines.engine import EngineConfig, parse_engine_config
from mimickit.envs.env_config import (
    ADDEnvConfig,
    AMPEnvConfig,
    ASEEnvConfig,
    CharDofTestEnvConfig,
    CharEnvConfig,
    DeepMimicEnvConfig,
    SMPEnvConfig,
    StaticObjectsEnvConfig,
    TaskDodgeballEnvConfig,
    TaskLocationEnvConfig,
    TaskSteeringEnvConfig,
    ViewMotionEnvConfig,
)
from mimickit.envs.sim_env import SimEnv
from mimickit.util.config import load_yaml, parse_config, unknown_key
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA, DataPaths
from mimickit.util.registry import Entry, Registry
from mimickit.util.warn import warn

# Engine keys that only Isaac Gym / Isaac Lab read; MimicKit env yamls may carry them.
_ISAAC_ONLY_KEYS = {"sim", "plane", "physx"}
# Keys that describe the task rather than one engine's physics: kept when an env yaml's engine block
# names another engine than the one chosen.
_PORTABLE_ENGINE_KEYS = {"control_mode", "control_freq", "env_spacing", "ground_contact_height", "ball_joint_limits"}
TOP_LEVEL_KEYS = ("env_name", "env", "engine")  # of MimicKit's layout, with the env's fields under env:

ENVS: Registry[CharEnvConfig, SimEnv] = Registry(
    "env",
    "mimickit.envs.sim_env:SimEnv",
    {
        "char": Entry(CharEnvConfig, "mimickit.envs.char_env:CharEnv"),
        "deepmimic": Entry(DeepMimicEnvConfig, "mimickit.envs.deepmimic_env:DeepMimicEnv"),
        "static_objects": Entry(StaticObjectsEnvConfig, "mimickit.envs.static_objects_env:StaticObjectsEnv"),
        "amp": Entry(AMPEnvConfig, "mimickit.envs.amp_env:AMPEnv"),
        "add": Entry(ADDEnvConfig, "mimickit.envs.add_env:ADDEnv"),
        "ase": Entry(ASEEnvConfig, "mimickit.envs.ase_env:ASEEnv"),
        "smp": Entry(SMPEnvConfig, "mimickit.envs.smp_env:SMPEnv"),
        "task_location": Entry(TaskLocationEnvConfig, "mimickit.envs.task_location_env:TaskLocationEnv"),
        "task_steering": Entry(TaskSteeringEnvConfig, "mimickit.envs.task_steering_env:TaskSteeringEnv"),
        "task_dodgeball": Entry(TaskDodgeballEnvConfig, "mimickit.envs.task_dodgeball_env:TaskDodgeballEnv"),
        "view_motion": Entry(ViewMotionEnvConfig, "mimickit.envs.view_motion_env:ViewMotionEnv"),
        "char_dof_test": Entry(CharDofTestEnvConfig, "mimickit.envs.char_dof_test_env:CharDofTestEnv"),
    },
)
"""Every env by its yaml `env_name`: `load_env_configs` and the builders below use this table."""


def parse_env_config(raw: dict, env_file: str | Path) -> CharEnvConfig:
    """The env config of a loaded env yaml `raw` (fields under `env:` or at the top), validated by the
    config class of its `env_name`."""
    env_name = raw.get("env_name")
    if env_name is None:
        raise MimicKitError(f"{env_file}: missing required key 'env_name'")
    if env_name not in ENVS:
        raise MimicKitError(f"{env_file}: key 'env_name': {ENVS.unknown(env_name)}")
    return parse_config(ENVS.config_class(env_name), {**env_fields(raw, env_file), "env_name": env_name}, env_file)


def load_env_configs(
    env_file: str | Path, engine_file: str | Path | None, motion_file: str | Path | None = None
) -> tuple[CharEnvConfig, EngineConfig]:
    """Read and validate an env yaml and an engine yaml (the env's `engine:` block merged in);
    `motion_file` (`--motion_file`) replaces the env's clip or dataset."""
    raw = load_yaml(env_file)
    env_cfg = parse_env_config(raw, env_file)
    env_name = env_cfg.env_name
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


def env_fields(raw: dict[str, Any], env_file: str | Path) -> dict[str, Any]:
    """The env's fields of an env yaml: its `env:` block, beside which only `env_name` and `engine`
    may stand (MimicKit's layout), or, without a block, every top-level key but those two."""
    if not isinstance(raw.get("env"), dict):
        return {k: v for k, v in raw.items() if k not in ("env_name", "engine")}
    env_keys = set(ENVS.config_class(raw["env_name"]).model_fields) - {"env_name"}
    for key in raw:
        if key in TOP_LEVEL_KEYS:
            continue
        if key in env_keys:
            raise MimicKitError(
                f"{env_file}: key '{key}' stands beside the env: block, where it is not read; move it into env:"
            )
        problem = unknown_key(key, [*TOP_LEVEL_KEYS, *env_keys], " beside the env: block")
        raise MimicKitError(
            f"{env_file}: {problem}; only {', '.join(TOP_LEVEL_KEYS)} go there, the env's fields under env:"
        )
    return dict(raw["env"])


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
