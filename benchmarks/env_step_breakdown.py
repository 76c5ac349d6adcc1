"""Where an env step's time goes beyond raw physics, on the MuJoCo engine (figures, not tests).

    python benchmarks/env_step_breakdown.py [--num_envs 256] [--steps 160]

Runs the bench loop (random actions, done envs reset) and alternates, step by step, the variants it
compares, so that a load that comes and goes on a shared machine weighs on both alike. Prints medians:
- `engine_step_ms` vs `replay_rollout_ms`: the engine's step alone (commands in, state gathered) and
  `mujoco.rollout` re-running that same step from the same start state, warm start and controls;
- `clock_concurrent_ms` vs `clock_serial_ms`: the physics step with the env's clock work run
  concurrently (`Engine.step(concurrent=...)`) vs run before it, and `clock_alone_ms`, its cost alone;
- `tail_idle_ms`: per worker pass, the time between the first and the last thread finishing (a core
  idles that long), summed per control step.
"""

from __future__ import annotations

import argparse
import json
import statistics
import threading
import time
from collections import defaultdict
from collections.abc import Callable

import torch

from mimickit.engines.bench_util import RawRollout
from mimickit.engines.mujoco_engine import MujocoEngine
from mimickit.envs.base_env import DoneFlags
from mimickit.envs.env_builder import build_env


def _instrument_tail_idle(engine: MujocoEngine, idle: list[float]) -> None:
    """Record, per `_run_workers` pass, how long the first thread to finish waited for the last."""
    run_workers, step_chunk = engine._run_workers, engine._step_chunk
    ends: dict[int, float] = {}

    def timed_chunk(rows: slice, nstep: int, first: bool, last: bool) -> None:
        step_chunk(rows, nstep, first, last)
        ends[threading.get_ident()] = time.perf_counter()

    def timed_pass(nstep: int, first: bool, last: bool, concurrent: Callable[[], None] | None = None) -> None:
        ends.clear()
        run_workers(nstep, first, last, concurrent)
        if len(ends) > 1:
            idle.append(max(ends.values()) - min(ends.values()))

    engine._step_chunk, engine._run_workers = timed_chunk, timed_pass


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--engine_config", default="data/engines/mujoco_engine.yaml")
    ap.add_argument("--env_config", default="data/envs/deepmimic_humanoid_env.yaml")
    ap.add_argument("--num_envs", type=int, default=256)
    ap.add_argument("--steps", type=int, default=160)
    args = ap.parse_args()

    n = args.num_envs
    env = build_env(args.env_config, args.engine_config, n, "cpu")
    engine = env.engine
    raw = RawRollout(engine.mj_model, engine.mj_datas, engine.num_threads, engine.config.substeps)
    idle: list[float] = []
    _instrument_tail_idle(engine, idle)
    space = env.get_action_space()
    low, high = torch.as_tensor(space.low), torch.as_tensor(space.high)
    gen = torch.Generator().manual_seed(0)
    times: dict[str, list[float]] = defaultdict(list)
    with torch.inference_mode():
        env.reset()
        for i in range(args.steps + 10):
            env._apply_action(low + (high - low) * torch.rand(n, low.shape[0], generator=gen))
            state, warm = engine.physics_state()
            idle_before = len(idle)
            start = time.perf_counter()
            if i % 3 == 0:
                engine.step()
                key = "engine_step_ms"
            elif i % 3 == 1:
                engine.step(concurrent=env._update_clock)
                key = "clock_concurrent_ms"
            else:
                env._update_clock()
                times["clock_alone_ms"].append(time.perf_counter() - start)
                engine.step()
                key = "clock_serial_ms"
            times[key].append(time.perf_counter() - start)
            times["tail_idle_ms"].append(sum(idle[idle_before:]))
            if key == "engine_step_ms":
                times["replay_rollout_ms"].append(raw.replay(state, warm, engine.get_ctrl()))
                env._update_clock()  # untimed: keeps the env's time and reference in step
            with env._frozen_state():
                env._update_info()
                env._update_done()
            ended = torch.nonzero(env._done_buf != DoneFlags.NULL).flatten()
            if len(ended):
                env.reset(ended)
    raw.close()
    skip = 10 // 3  # warm-up steps of each variant
    result = {k: round(statistics.median(v[skip:]) * 1e3, 3) for k, v in times.items()}
    result["replay_over_engine"] = round(result["replay_rollout_ms"] / result["engine_step_ms"], 3)
    print(json.dumps({"num_envs": n, "steps": args.steps, **result}))


if __name__ == "__main__":
    main()
