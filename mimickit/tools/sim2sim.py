"""sim2sim: the same policy (or PD tracking of a clip) from the same initial state in two engines.

Both engines run the arg file's env (DeepMimic family: it has a reference motion) with one env each,
starting at clip time 0 (`rand_reset` off), in lockstep. The driver is either a checkpoint (the
deterministic policy, one copy per engine, each fed its own engine's observations) or a clip (the PD
targets are the clip's DoF positions one control step ahead). Each engine runs until its env terminates
(fall, pose error, clip end) or `seconds` pass; the engines are compared while both still run.

Series, one value per control step (metres):
* `root_pos_diff_m`, `body_pos_diff_m`: root and mean body position distance between the two engines;
* `tracking[engine].root_pos_err_m`, `.body_pos_err_m`: each engine against the reference clip.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from mimickit.envs.base_env import DoneFlags
from mimickit.envs.env_builder import build_env_from_configs, load_env_configs
from mimickit.envs.sim_env import SimEnv
from mimickit.learning.agent_builder import build_agent
from mimickit.runner.policy import policy_inputs
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA, DataPaths

ENGINE_NAMES = ("mujoco", "newton")


@dataclass
class _Run:
    """One engine's env, its driver, and its per-step records."""

    engine: str
    env: SimEnv
    agent: Any | None
    obs: torch.Tensor
    alive: bool = True
    steps: int = 0
    done_flag: str = "horizon"  # until the env terminates: its DoneFlags name
    root_pos: list[torch.Tensor] = field(default_factory=list)  # [3] per step
    body_pos: list[torch.Tensor] = field(default_factory=list)  # [B, 3] per step
    root_err: list[float] = field(default_factory=list)
    body_err: list[float] = field(default_factory=list)


def _make_run(
    engine: str, arg_file: str, model_file: str | None, motion_file: str | None, data_paths: DataPaths
) -> _Run:
    inputs = policy_inputs(arg_file, data_paths)  # the configs and the arg file's --motion_file
    env_cfg, engine_cfg = load_env_configs(inputs.env_file, inputs.engine_file)
    if not hasattr(env_cfg, "motion_file"):
        raise MimicKitError(f"{inputs.env_file}: sim2sim needs an env with a reference motion (deepmimic, add, amp)")
    motion = str(data_paths.resolve(motion_file)) if motion_file else inputs.motion_file
    updates: dict[str, Any] = {"rand_reset": False}  # both engines start at clip time 0
    if motion:
        updates["motion_file"] = motion
    env_cfg = env_cfg.model_copy(update=updates)
    # The arg file's physics (rates, control mode) with only the engine swapped.
    engine_cfg = engine_cfg.model_copy(update={"engine_name": engine})
    env = build_env_from_configs(env_cfg, engine_cfg, 1, data_paths=data_paths)
    agent = None
    if model_file:
        agent = build_agent(inputs.agent_file, env, verbose=False)
        agent.load(model_file)
    obs, _ = env.reset()
    return _Run(engine, env, agent, obs.clone())


def _clip_targets(env: SimEnv) -> torch.Tensor:
    """[1, D] the clip's DoF positions one control step ahead: PD targets for tracking it."""
    time = env.get_motion_time() + env.engine.get_timestep()
    f = env.motion_lib.calc_motion_frame(torch.zeros(1, dtype=torch.long), time)
    return env.char_model.rot_to_dof(f.joint_rot)


def _step(run: _Run) -> None:
    env = run.env
    action = run.agent.compute_action(run.obs) if run.agent is not None else _clip_targets(env)
    obs, _, done, _ = env.step(action)
    run.obs = obs.clone()
    run.steps += 1
    char = env.get_char_id()
    body = env.engine.get_body_pos(char)[0].clone()
    ref = env.get_ref_state()
    run.root_pos.append(body[0])
    run.body_pos.append(body)
    run.root_err.append((body[0] - ref["root_pos"][0]).norm().item())
    run.body_err.append((body - ref["body_pos"][0]).norm(dim=-1).mean().item())
    flag = int(done[0])
    if flag != DoneFlags.NULL:
        run.alive = False
        run.done_flag = DoneFlags(flag).name.lower()


def _summary(values: list[float], dt: float) -> dict[str, float]:
    if not values:
        return {}
    t = torch.tensor(values)
    at_1s = values[min(len(values), round(1.0 / dt)) - 1]
    return {"mean": t.mean().item(), "max": t.max().item(), "at_1s": at_1s, "final": values[-1]}


def run_sim2sim(
    arg_file: str,
    model_file: str | None = None,
    motion_file: str | None = None,
    engines: tuple[str, str] = ENGINE_NAMES,
    seconds: float = 5.0,
    data_paths: DataPaths = PROJECT_DATA,
) -> dict[str, Any]:
    """Run both engines and return the report (see the module docstring); series are lists per step.
    `data/...` paths (the arg file's, its configs' and `motion_file`) are found by `data_paths`."""
    if (model_file is None) == (motion_file is None):
        raise MimicKitError("sim2sim: give exactly one of --model_file (a policy) or --motion_file (PD tracking)")
    if len(engines) != 2 or len(set(engines)) != 2:
        raise MimicKitError(f"sim2sim compares two different engines, got {list(engines)}")
    runs = [_make_run(e, arg_file, model_file, motion_file, data_paths) for e in engines]
    dt = runs[0].env.engine.get_timestep()
    for _ in range(round(seconds / dt)):
        live = [r for r in runs if r.alive]
        if not live:
            break
        for r in live:
            _step(r)
    common = min(r.steps for r in runs)
    a, b = runs
    root_diff = [(a.root_pos[i] - b.root_pos[i]).norm().item() for i in range(common)]
    body_diff = [(a.body_pos[i] - b.body_pos[i]).norm(dim=-1).mean().item() for i in range(common)]
    return {
        "engines": list(engines),
        "driver": "policy" if model_file else "clip_pd",
        "source": model_file or motion_file,
        "dt": dt,
        "seconds": seconds,
        "common_steps": common,
        "episode_length": {r.engine: r.steps for r in runs},
        "episode_seconds": {r.engine: r.steps * dt for r in runs},
        "termination": {r.engine: r.done_flag for r in runs},
        "root_pos_diff_m": root_diff,
        "body_pos_diff_m": body_diff,
        "tracking": {r.engine: {"root_pos_err_m": r.root_err, "body_pos_err_m": r.body_err} for r in runs},
        "summary": {
            "root_pos_diff_m": _summary(root_diff, dt),
            "body_pos_diff_m": _summary(body_diff, dt),
            **{f"{r.engine}.body_pos_err_m": _summary(r.body_err, dt) for r in runs},
        },
    }


def format_report(report: dict[str, Any], every_s: float = 0.5) -> str:
    """A table every `every_s` seconds of the common horizon, then episode lengths."""
    a, b = report["engines"]
    dt, track = report["dt"], report["tracking"]
    lines = [
        f"sim2sim {a} vs {b}, {report['driver']} ({Path(report['source']).name}), dt {dt:.4f} s",
        f"{'t (s)':>6} {'root Δ (m)':>11} {'body Δ (m)':>11} {a + ' err':>12} {b + ' err':>12}",
    ]
    stride = max(1, round(every_s / dt))
    for i in range(stride - 1, report["common_steps"], stride):
        lines.append(
            f"{(i + 1) * dt:6.2f} {report['root_pos_diff_m'][i]:11.4f} {report['body_pos_diff_m'][i]:11.4f} "
            f"{track[a]['body_pos_err_m'][i]:12.4f} {track[b]['body_pos_err_m'][i]:12.4f}"
        )
    for e in (a, b):
        lines.append(
            f"{e}: episode {report['episode_length'][e]} steps ({report['episode_seconds'][e]:.2f} s), "
            f"ended by {report['termination'][e]}"
        )
    return "\n".join(lines)
