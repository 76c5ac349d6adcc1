"""`mimickit bench`: env throughput with random actions against raw MuJoCo on the same model.

Both figures come from the same run, so their ratio is meaningful on a noisy machine:
ratio = env_steps_per_s × substeps / raw_sim_steps_per_s.

Raw rollout's speed depends on the states it simulates, so there are two baselines. `free` (the default):
rollout advances its own copies of the envs' states with zero controls, never resetting. `replay`: rollout
re-runs every env step just timed, from the same start states (reset edits included), solver warm starts
and controls, i.e. the same physics work the env did.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from mimickit.engines.bench_util import raw_rollout
from mimickit.engines.engine import ControlMode
from mimickit.envs.base_env import DoneFlags
from mimickit.envs.env_builder import build_env
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA, DataPaths
from mimickit.util.threads import torch_threads

RAW_MODES = ("free", "replay")


def run_bench(
    engine_config: str,
    env_config: str,
    num_envs: int,
    steps: int,
    warmup: int = 10,
    rounds: int = 5,
    raw_mode: str = "free",
    data_paths: DataPaths = PROJECT_DATA,
) -> dict[str, Any]:
    """Env steps and raw rollout calls alternate in `rounds` rounds of steps/rounds control steps each,
    so a load that comes and goes on a shared machine weighs on both figures alike."""
    if raw_mode not in RAW_MODES:
        raise MimicKitError(f"raw mode {raw_mode!r}: choose one of {', '.join(RAW_MODES)}")
    env = build_env(env_config, engine_config, num_envs, "cpu", data_paths=data_paths)
    one_step = random_action_step(env)
    env.reset()
    engine = env.engine
    substeps = engine.config.substeps
    rounds = max(1, min(rounds, steps))
    per_round = [steps // rounds + (r < steps % rounds) for r in range(rounds)]
    env_time, raw_time, ratios = 0.0, 0.0, []
    # As in a training rollout: no autograd bookkeeping, torch on one thread (the env's tensors are small).
    with torch.inference_mode(), torch_threads(1):
        for _ in range(warmup):
            one_step()
        raw = raw_rollout(engine)  # None for an engine without a raw MuJoCo baseline: env figures only
        replay = raw is not None and raw_mode == "replay"
        if replay and engine.config.control_mode == ControlMode.pd_explicit:
            raise MimicKitError("--raw replay needs controls held over a step; pd_explicit recomputes them per substep")
        env.profiler.reset()
        for n in per_round:
            env.profiler.enabled = True
            t_env, record = _timed_steps(one_step, n, engine if replay else None)
            env.profiler.enabled = False
            env_time += t_env
            if raw is not None:
                if replay:
                    t_raw = sum(raw.replay(*r) for r in record)
                else:
                    t_raw = sum(raw.step(np.zeros((num_envs, raw.model.nu))) for _ in range(n))
                raw_time += t_raw
                ratios.append(t_raw / t_env)
        if raw is not None:
            raw.close()
    env_sps = steps * num_envs / env_time
    raw_sps = steps * num_envs * substeps / raw_time if raw is not None else None
    return {
        "num_envs": num_envs,
        "steps": steps,
        "raw_mode": raw_mode if raw is not None else None,
        "substeps": substeps,
        "env_steps_per_s": round(env_sps, 1),
        "engine": engine.get_name(),
        "raw_sim_steps_per_s": round(raw_sps, 1) if raw_sps else None,
        "ratio": round(env_sps * substeps / raw_sps, 4) if raw_sps else None,
        "ratio_per_round": [round(r, 4) for r in ratios],
        "profile": {k: round(v, 4) for k, v in env.profiler.shares().items()},
    }


def random_action_step(env: Any, seed: int = 0) -> Callable[[], None]:
    """The bench's control step: uniform random actions within the env's action space (no network), then
    a reset of the envs that are done."""
    space = env.get_action_space()
    low, high = torch.as_tensor(space.low), torch.as_tensor(space.high)
    gen = torch.Generator().manual_seed(seed)

    def one_step() -> None:
        action = low + (high - low) * torch.rand(env.num_envs, low.shape[0], generator=gen)
        _, _, done, _ = env.step(action)
        ended = torch.nonzero(done != DoneFlags.NULL).flatten()
        if len(ended):
            env.reset(ended)

    return one_step


def _timed_steps(one_step: Callable[[], None], n: int, engine: Any | None) -> tuple[float, list[tuple]]:
    """Seconds of n env steps; with `engine`, also each step's (start state, warm start, controls), taken
    outside the timed part."""
    elapsed, record = 0.0, []
    if engine is None:
        start = time.perf_counter()
        for _ in range(n):
            one_step()
        return time.perf_counter() - start, record
    for _ in range(n):
        state, warm = engine.physics_state()
        start = time.perf_counter()
        one_step()
        elapsed += time.perf_counter() - start
        record.append((state, warm, engine.get_ctrl()))
    return elapsed, record


def format_bench(result: dict[str, Any]) -> str:
    lines = [
        f"{result['engine']}: {result['num_envs']} envs × {result['steps']} steps, {result['substeps']} substeps",
        f"  env steps/s         {result['env_steps_per_s']:>12,.0f}",
    ]
    if result["raw_sim_steps_per_s"] is not None:
        lines += [
            f"  raw sim steps/s     {result['raw_sim_steps_per_s']:>12,.0f}   ({result['raw_mode']} rollout)",
            f"  ratio               {result['ratio']:>12.3f}   per round: "
            + " ".join(f"{r:.2f}" for r in result["ratio_per_round"]),
        ]
    lines += [
        "  time share of env steps: " + ", ".join(f"{k} {v:.0%}" for k, v in result["profile"].items()),
    ]
    return "\n".join(lines)
