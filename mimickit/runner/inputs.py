"""What a run reads: the config files and `--motion_file` an arg file names, resolved and checked before
anything starts (`resolve_inputs` → `RunInputs`), and the env they describe (`build_run_env`).

`mimickit train|test` (`mimickit/run.py`), `mimickit eval` and `video`, the studio's rollouts and
`runner.policy` all resolve an arg file here, so each plays the env that `mimickit test` would.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from mimickit.util.arg_parser import ArgParser
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA, DataPaths


@dataclass
class RunInputs:
    """The files a run reads, resolved and checked before anything starts."""

    env_file: str
    engine_file: str | None
    agent_file: str | None
    motion_file: str | None
    """`--motion_file`, resolved (None: the env config's own clip or dataset)."""
    data_paths: DataPaths = PROJECT_DATA
    """Where the configs' `data/...` files are found (`--data_dir`, then the project's data)."""


def resolve_inputs(args: ArgParser, data_paths: DataPaths | None = None) -> RunInputs:
    """The config files and `--motion_file`, each checked to exist (one error line otherwise), found
    by `data_paths` (by default `--data_dir`'s, then the project's data)."""
    paths = data_paths or DataPaths(args.parse_string("data_dir", "") or None)
    motion = args.parse_string("motion_file", "")
    if args.has_key("motion_file") and not motion:
        raise MimicKitError("--motion_file needs a value (a .pkl clip or a dataset .yaml)")
    motion_path = paths.resolve(motion) if motion else None
    if motion_path is not None and not motion_path.is_file():
        raise MimicKitError(f"--motion_file: file not found: {motion}")
    return RunInputs(
        env_file=_config_path(args, "env_config", paths, required=True) or "",
        engine_file=_config_path(args, "engine_config", paths),
        agent_file=_config_path(args, "agent_config", paths),
        motion_file=str(motion_path) if motion_path is not None else None,
        data_paths=paths,
    )


def build_run_env(inputs: RunInputs, num_envs: int, device: str) -> tuple[Any, dict[str, Any]]:
    """The env of the configs, `--motion_file` replacing the env config's clip or dataset; plus what
    args.json records about it (env_name, char_file, the motion file trained on and where it came from)."""
    from mimickit.envs.env_builder import build_env_from_configs, load_env_configs

    env_cfg, engine_cfg = load_env_configs(inputs.env_file, inputs.engine_file, inputs.motion_file)
    motion = getattr(env_cfg, "motion_file", None)
    info = {
        "env_name": env_cfg.env_name,
        "char_file": str(inputs.data_paths.resolve(env_cfg.char_file)),
        "motion_file": str(inputs.data_paths.resolve(motion)) if motion else None,
        "motion_file_from": None if not motion else ("--motion_file" if inputs.motion_file else "env_config"),
        "engine_name": engine_cfg.engine_name,
    }
    env = build_env_from_configs(env_cfg, engine_cfg, num_envs, device, visualize=False, data_paths=inputs.data_paths)
    return env, info


def _config_path(args: ArgParser, key: str, data_paths: DataPaths, required: bool = False) -> str | None:
    value = args.parse_string(key, "")
    if not value:
        if required:
            raise MimicKitError(f"--{key} is required")
        return None
    path = data_paths.resolve(value)
    if not path.is_file():
        raise MimicKitError(f"--{key}: file not found: {value}")
    return str(path)
