"""Checkpoint inspection: what a `model.pt` holds and whether it fits an env or a character.

A checkpoint is a torch state_dict (read with `weights_only=True` only: no code runs on load):
normalisers `_obs_norm.*` / `_a_norm.*`, the networks `_model.*`, and, for checkpoints written by
this project's trainer, `_train_state` (agent name, iteration, samples, test result, optimisers).
The agent type comes from `_train_state` when present, else from the key names: actor/critic only
is PPO or AWR (they share their keys), discriminator keys (`_disc`) mean AMP or ADD, encoder keys
(`_enc`) ASE.

Fitting is decided by sizes: the observation size (`_obs_norm._mean`) and the action size
(`_a_norm._mean`) against the spaces of an env built from an env config (one env, no drawing), or
the action size against a character's DoF count.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import torch

from mimickit.learning.checkpoint import nonfinite_tensors, read_checkpoint
from mimickit.learning.run_folder import AGENT_CONFIG_FILE, ENGINE_CONFIG_FILE, ENV_CONFIG_FILE
from mimickit.util.arg_parser import ArgParser
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_ROOT, DataPaths
from mimickit.util.warn import collect_warnings

TRAIN_STATE_KEY = "_train_state"
CONFIG_FILES = (ENV_CONFIG_FILE, ENGINE_CONFIG_FILE, AGENT_CONFIG_FILE)
MOTION_FILE = "motion_file"  # configs_from_arg_file's key for an arg file's `--motion_file`


def load_state(path: Path) -> dict[str, Any]:
    """The checkpoint's state dict; MimicKitError (one line) when it is not a readable checkpoint
    (the trainer's reader: `weights_only=True`, a size limit, every value and `_train_state` checked)."""
    return read_checkpoint(path)


def nonfinite_message(path: Path, state: dict[str, Any]) -> tuple[list[str], str | None]:
    """(the model tensors holding NaN or inf, and the one line that says so; None when all are finite)."""
    model = {k: v for k, v in state.items() if k != TRAIN_STATE_KEY}
    bad = nonfinite_tensors(model)
    if not bad:
        return [], None
    shown = ", ".join(bad[:4]) + (f" and {len(bad) - 4} more" if len(bad) > 4 else "")
    return bad, f"non-finite weights (NaN or inf) in {shown}: the run that wrote it diverged; it cannot be rolled out"


def check_finite_checkpoint(path: Path) -> None:
    """MimicKitError (one line) when the checkpoint cannot be read or holds non-finite weights:
    checked before a rollout builds its env, so a diverged checkpoint is refused at once."""
    _, message = nonfinite_message(path, load_state(path))
    if message is not None:
        raise MimicKitError(f"{path}: {message}")


def agent_type(state: dict[str, Any]) -> tuple[str, str]:
    """(agent type, how it was told) from `_train_state` or the key names."""
    ts = state.get(TRAIN_STATE_KEY)
    if isinstance(ts, dict) and ts.get("agent_name"):
        return str(ts["agent_name"]), "named in _train_state"
    keys = [k for k in state if k != TRAIN_STATE_KEY]
    if any(k.startswith("_prior_model.") for k in keys):
        return "SMP", "motion prior keys (_prior_model)"
    if any("_enc" in k for k in keys):
        return "ASE", "encoder keys (_enc)"
    if any("_disc" in k for k in keys):
        return "AMP or ADD", "discriminator keys (_disc)"
    if any(k.startswith("_model._actor_layers") for k in keys):
        return "PPO or AWR", "actor/critic keys only (PPO and AWR share their keys)"
    return "unknown", "no actor keys (_model._actor_layers)"


def _layer_order(key: str) -> tuple[str, int]:
    m = re.search(r"\.(\d+)\.weight$", key)
    return (key.rsplit(".", 2)[0] if m else key, int(m.group(1)) if m else -1)


def network_layers(state: dict[str, Any]) -> dict[str, list[dict[str, Any]]]:
    """Weight shapes per network (actor, action head, critic, discriminator, encoder, other), in order.
    A linear layer's weight is [out, in]; `in`/`out` are given too."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for key in sorted((k for k in state if k.startswith("_model.")), key=_layer_order):
        value = state[key]
        if not isinstance(value, torch.Tensor) or not (key.endswith("weight") or key.endswith("_logstd_net")):
            continue
        name = key.removeprefix("_model.")
        group = (
            "actor" if name.startswith("_actor")
            else "action_head" if name.startswith("_action_dist")
            else "critic" if name.startswith("_critic")
            else "discriminator" if name.startswith("_disc")
            else "encoder" if name.startswith("_enc")
            else "other"
        )  # fmt: skip
        entry: dict[str, Any] = {"key": key, "shape": list(value.shape)}
        if value.dim() == 2:
            entry["in"], entry["out"] = int(value.shape[1]), int(value.shape[0])
        groups.setdefault(group, []).append(entry)
    return groups


def normalizer_stats(state: dict[str, Any], prefix: str) -> dict[str, Any] | None:
    """count, mean |μ|, mean σ and the per-dimension min/max of μ and σ of one normaliser."""
    mean, std = state.get(f"{prefix}._mean"), state.get(f"{prefix}._std")
    if not isinstance(mean, torch.Tensor) or not isinstance(std, torch.Tensor):
        return None
    count = state.get(f"{prefix}._count")
    mean, std = mean.double().flatten(), std.double().flatten()
    return {
        "size": int(mean.numel()),
        "count": int(count.flatten()[0]) if isinstance(count, torch.Tensor) and count.numel() else None,
        "mean_abs_mean": float(mean.abs().mean()) if mean.numel() else 0.0,
        "mean_std": float(std.mean()) if std.numel() else 0.0,
        "mean_min": float(mean.min()) if mean.numel() else 0.0,
        "mean_max": float(mean.max()) if mean.numel() else 0.0,
        "std_min": float(std.min()) if std.numel() else 0.0,
        "std_max": float(std.max()) if std.numel() else 0.0,
    }


def sizes(state: dict[str, Any]) -> tuple[int | None, int | None]:
    """(observation size, action size) the checkpoint was trained with."""
    obs = state.get("_obs_norm._mean")
    act = state.get("_a_norm._mean")
    if not isinstance(act, torch.Tensor):
        act = state.get("_model._action_dist._mean_net.weight")
        act_size = int(act.shape[0]) if isinstance(act, torch.Tensor) else None
    else:
        act_size = int(act.numel())
    if isinstance(obs, torch.Tensor):
        obs_size = int(obs.numel())
    else:
        first = state.get("_model._actor_layers.0.weight")
        obs_size = int(first.shape[1]) if isinstance(first, torch.Tensor) and first.dim() == 2 else None
    return obs_size, act_size


def train_state_summary(state: dict[str, Any]) -> dict[str, Any] | None:
    ts = state.get(TRAIN_STATE_KEY)
    if not isinstance(ts, dict):
        return None
    iteration, samples = int(ts.get("iteration", 0)), int(ts.get("samples", 0))
    return {
        "agent_name": ts.get("agent_name"),
        "iteration": iteration,
        "samples": samples,
        "samples_per_iteration": round(samples / iteration, 1) if iteration else None,
        "wall_time_hours": float(ts.get("wall_time_hours", 0.0)),
        "test": ts.get("test"),
        "optimizers": sorted((ts.get("optimizers") or {}).keys()),
    }


def inspect_checkpoint(path: Path) -> dict[str, Any]:
    """Everything the inspection panel shows (see the module docstring)."""
    state = load_state(path)
    kind, reason = agent_type(state)
    obs_size, act_size = sizes(state)
    tensors = {k: v for k, v in state.items() if isinstance(v, torch.Tensor)}
    nonfinite, nonfinite_msg = nonfinite_message(path, state)
    st = path.stat()
    return {
        "path": str(path),
        "size_bytes": st.st_size,
        "mtime": st.st_mtime,
        "agent": kind,
        "agent_reason": reason,
        "obs_size": obs_size,
        "action_size": act_size,
        "num_params": int(sum(v.numel() for k, v in tensors.items() if k.startswith("_model."))),
        "networks": network_layers(state),
        "normalizers": {
            name: s
            for name, prefix in (("obs", "_obs_norm"), ("action", "_a_norm"))
            if (s := normalizer_stats(state, prefix)) is not None
        },
        "train_state": train_state_summary(state),
        "configs_beside": configs_beside(path),
        "nonfinite": nonfinite,
        "nonfinite_message": nonfinite_msg,
    }


def job_file(path: Path, given: str, what: str, suffixes: tuple[str, ...]) -> Path:
    """`path` (what `confine` made of `given`) if it is a regular file ending in one of `suffixes`:
    a folder, or another file of the runs folder (its `registry.sqlite`), is not a checkpoint, clip or
    config; MimicKitError (400) naming `what` otherwise."""
    shown = given[:200]
    if not path.is_file():
        raise MimicKitError(f"{what} {shown}: not a file")
    if path.suffix.lower() not in suffixes:
        raise MimicKitError(f"{what} {shown}: expected a {' or '.join(suffixes)} file")
    return path


def configs_beside(path: Path) -> dict[str, str]:
    """The run configs a trainer copied next to this checkpoint (model.pt, or int_models/x.pt), or
    those a shipped model's arg file names (`models/x_model.pt` beside `models/x_model.txt`), with its
    `--motion_file` (`configs_from_arg_file`)."""
    for folder in (path.parent, path.parent.parent):
        found = {name: str(folder / name) for name in CONFIG_FILES if (folder / name).is_file()}
        if ENV_CONFIG_FILE in found:
            return found
    sidecar = path.with_suffix(".txt")
    return configs_from_arg_file(sidecar, data_dir=path.parent.parent) if sidecar.is_file() else {}


def configs_from_arg_file(arg_file: Path, data_dir: Path) -> dict[str, str]:
    """`--env_config` / `--agent_config` / `--engine_config` of an arg file (keyed by their run-folder
    file names) and its `--motion_file` (key `MOTION_FILE`: the clip or dataset that replaces the env
    config's); `data/...` paths resolve in `data_dir` first, then in the project's data folder."""
    args = ArgParser()
    args.load_file(str(arg_file))
    keys = {name: name.removesuffix(".yaml") for name in CONFIG_FILES} | {MOTION_FILE: MOTION_FILE}
    found = {}
    for name, key in keys.items():
        value = args.parse_string(key, "")
        if not value:
            continue
        rel = Path(value)
        rest = Path(*rel.parts[1:]) if rel.parts[0] == "data" else None
        # Not `DataPaths.resolve`: a server request names no file in its working folder.
        candidates = [d / rest for d in DataPaths(data_dir).dirs()] if rest is not None else [PROJECT_ROOT / rel]
        hit = next((c for c in candidates if c.is_file()), None)
        if hit is None:
            raise MimicKitError(f"{arg_file}: --{key} {value}: file not found")
        found[name] = str(hit)
    return found if ENV_CONFIG_FILE in found else {}


# ------------------------------------------------------------------------------------------ fitting
_SPACES_CACHE: dict[tuple[str, int, str, int, str], tuple[int, int]] = {}


def env_spaces(env_file: Path, engine_file: Path | None, data_dir: Path | None) -> tuple[int, int]:
    """(observation size, action size) of the env `env_file` describes (one env is built; cached per
    file version)."""
    from mimickit.envs.env_builder import build_env  # torch/mujoco-heavy: only when asked

    key = (
        str(env_file), env_file.stat().st_mtime_ns,
        str(engine_file), engine_file.stat().st_mtime_ns if engine_file else 0,
        str(data_dir),
    )  # fmt: skip
    if key in _SPACES_CACHE:
        return _SPACES_CACHE[key]
    with collect_warnings():  # the fit is the answer; the build's warnings show when it is rolled out
        env = build_env(env_file, engine_file, 1, "cpu", visualize=False, data_paths=DataPaths(data_dir))
    try:
        spaces = (int(env.get_obs_space().shape[0]), int(env.get_action_space().shape[0]))
    finally:
        close = getattr(getattr(env, "engine", None), "close", None)
        if close:
            close()
    _SPACES_CACHE[key] = spaces
    return spaces


def fit_message(ckpt: tuple[int | None, int | None], target: tuple[int | None, int | None], what: str) -> str | None:
    """None when the sizes agree, else one sentence saying which differs."""
    (c_obs, c_act), (t_obs, t_act) = ckpt, target
    problems = []
    if t_obs is not None and c_obs is not None and c_obs != t_obs:
        problems.append(f"observations of {c_obs} values, {what} gives {t_obs}")
    if t_act is not None and c_act is not None and c_act != t_act:
        problems.append(f"actions of {c_act} values, {what} takes {t_act}")
    if not problems:
        return None
    hint = "a different env config or character?" if len(problems) == 2 or c_obs != t_obs else "a different character?"
    return f"the checkpoint does not fit {what}: it was trained on " + " and ".join(problems) + f" ({hint})"


def check_fit_env(
    path: Path, env_file: Path, engine_file: Path | None, data_dir: Path | None, shown: str
) -> dict[str, Any]:
    obs, act = sizes(load_state(path))
    t_obs, t_act = env_spaces(env_file, engine_file, data_dir)
    message = fit_message((obs, act), (t_obs, t_act), shown)
    return {
        "target": shown,
        "kind": "env_config",
        "fits": message is None,
        "message": message or f"fits {shown}: observations {t_obs}, actions {t_act}",
        "obs_size": t_obs,
        "action_size": t_act,
    }


def check_fit_char(path: Path, char_file: Path, shown: str) -> dict[str, Any]:
    """A character alone fixes the action size (one PD target per DoF), not the observation size."""
    from mimickit.anim.mjcf_char_model import load_char_model

    obs, act = sizes(load_state(path))
    with collect_warnings():
        dofs = load_char_model(char_file).get_dof_size()
    message = fit_message((obs, act), (None, dofs), shown)
    return {
        "target": shown,
        "kind": "char",
        "fits": message is None,
        "message": message or f"fits {shown}: {dofs} DoFs, one action each (observations depend on the env config)",
        "obs_size": None,
        "action_size": dofs,
    }
