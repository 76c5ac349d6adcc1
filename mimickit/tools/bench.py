"""`mimickit bench`: env throughput with random actions against raw MuJoCo on the same model.

Both figures come from the same run, so their ratio is meaningful on a noisy machine:
ratio = env_steps_per_s × substeps / raw_sim_steps_per_s.
"""

from __future__ import annotations

import time
from typing import Any

import torch

from mimickit.envs.base_env import DoneFlags
from mimickit.envs.env_builder import build_env


def run_bench(engine_config: str, env_config: str, num_envs: int, steps: int, warmup: int = 10) -> dict[str, Any]:
    env = build_env(env_config, engine_config, num_envs, "cpu")
    space = env.get_action_space()
    low = torch.as_tensor(space.low)
    high = torch.as_tensor(space.high)
    gen = torch.Generator().manual_seed(0)
    env.reset()

    def one_step() -> None:
        action = low + (high - low) * torch.rand(num_envs, low.shape[0], generator=gen)
        _, _, done, _ = env.step(action)
        ended = torch.nonzero(done != DoneFlags.NULL).flatten()
        if len(ended):
            env.reset(ended)

    with torch.inference_mode():  # as in a training rollout: no autograd bookkeeping
        for _ in range(warmup):
            one_step()
        env.profiler.reset()
        env.profiler.enabled = True
        start = time.perf_counter()
        for _ in range(steps):
            one_step()
        elapsed = time.perf_counter() - start
        env.profiler.enabled = False

    engine = env.engine
    substeps = engine.config.substeps
    raw = raw_throughput(engine, steps * substeps, substeps)
    env_sps = steps * num_envs / elapsed
    return {
        "num_envs": num_envs,
        "steps": steps,
        "substeps": substeps,
        "env_steps_per_s": round(env_sps, 1),
        "raw_sim_steps_per_s": round(raw, 1),
        "ratio": round(env_sps * substeps / raw, 4),
        "profile": {k: round(v, 4) for k, v in env.profiler.shares().items()},
    }


def raw_throughput(engine: Any, nsteps: int, substeps: int) -> float:
    """Raw `mujoco.rollout` sim steps/s on all cores over the engine's own compiled model and its envs'
    current states, called once per control step of `substeps` physics steps (state fed back)."""
    from mimickit.engines.bench_util import raw_rollout_steps_per_s

    return raw_rollout_steps_per_s(engine.mj_model, engine.mj_datas, nsteps, engine.num_threads, substeps=substeps)


def format_bench(result: dict[str, Any]) -> str:
    lines = [
        f"{result['num_envs']} envs × {result['steps']} steps, {result['substeps']} substeps",
        f"  env steps/s         {result['env_steps_per_s']:>12,.0f}",
        f"  raw sim steps/s     {result['raw_sim_steps_per_s']:>12,.0f}",
        f"  ratio               {result['ratio']:>12.3f}",
        "  time share of env steps: " + ", ".join(f"{k} {v:.0%}" for k, v in result["profile"].items()),
    ]
    return "\n".join(lines)
