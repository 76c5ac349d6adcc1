"""Where an env step's time goes beyond raw physics, on the MuJoCo engine (figures, not tests).

    python benchmarks/env_step_breakdown.py [--num_envs 256] [--steps 400]

Runs the bench loop (random actions, done envs reset) and alternates, two steps at a time, the env step
as it is (the clock work run concurrently with the physics, `Engine.step(concurrent=...)`) and the same
step with the clock work run before the physics, so that a load that comes and goes on a shared machine
weighs on both alike. Prints medians per control step (step and reset):
- `env_step_concurrent_clock_ms`, `env_step_serial_clock_ms`;
- `replay_rollout_ms`: `mujoco.rollout` re-running each step's physics from the same start state, warm
  start and controls (the same work; timed apart from the env);
- `tail_idle_ms`: per worker pass, the time between the first and the last thread finishing (a core
  idles that long), summed over the step's passes.
"""

from __future__ import annotations

import argparse
import json
import statistics
import threading
import time
from collections import defaultdict
from collections.abc import Callable
from functools import partial

import torch

from mimickit.engines.bench_util import RawRollout
from mimickit.engines.mujoco_engine import MujocoEngine
from mimickit.envs.env_builder import build_env
from mimickit.tools.bench import random_action_step


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


def _clock_first(clock: Callable[[], None], step: Callable[..., None], concurrent: Callable[[], None]) -> None:
    """An engine step that runs the clock work before the physics instead of during it."""
    clock()
    step()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--engine_config", default="data/engines/mujoco_engine.yaml")
    ap.add_argument("--env_config", default="data/envs/deepmimic_humanoid_env.yaml")
    ap.add_argument("--num_envs", type=int, default=256)
    ap.add_argument("--steps", type=int, default=400)
    args = ap.parse_args()

    n = args.num_envs
    env = build_env(args.env_config, args.engine_config, n, "cpu")
    engine = env.engine
    raw = RawRollout(engine.mj_model, engine.mj_datas, engine.num_threads, engine.config.substeps)
    idle: list[float] = []
    _instrument_tail_idle(engine, idle)
    plain_step = engine.step
    one_step = random_action_step(env)
    times: dict[str, list[float]] = defaultdict(list)
    with torch.inference_mode():
        env.reset()
        for i in range(args.steps + 20):
            serial = (i // 2) % 2 == 1
            state, warm = engine.physics_state()
            idle_before = len(idle)
            if serial:
                engine.step = partial(_clock_first, env._update_clock, plain_step)
            start = time.perf_counter()
            one_step()
            elapsed = time.perf_counter() - start
            engine.step = plain_step
            if i < 20:
                continue
            times["env_step_serial_clock_ms" if serial else "env_step_concurrent_clock_ms"].append(elapsed)
            times["tail_idle_ms"].append(sum(idle[idle_before:]))
            times["replay_rollout_ms"].append(raw.replay(state, warm, engine.get_ctrl()))
    raw.close()
    result = {k: round(statistics.median(v) * 1e3, 3) for k, v in times.items()}
    print(json.dumps({"num_envs": n, "steps": args.steps, **result}))


if __name__ == "__main__":
    main()
