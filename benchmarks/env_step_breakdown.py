"""Where an env step's time goes beyond raw physics, on the MuJoCo engine (figures, not tests).

    python benchmarks/env_step_breakdown.py [--num_envs 256] [--steps 400]

Runs the bench loop (random actions, done envs reset) and alternates, two steps at a time, the env step
as it is (DeepMimic's clock work run on the calling thread while the engine's workers step the physics,
`Engine.stepping`) and the same step with the clock work run before the physics, so that a load that
comes and goes on a shared machine weighs on both alike. Prints medians per control step (step and reset):
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
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager

import torch

from mimickit.engines.bench_util import RawRollout
from mimickit.engines.mujoco_engine import MujocoEngine
from mimickit.envs.env_builder import build_env
from mimickit.tools.bench import random_action_step
from mimickit.util.threads import torch_threads


def _instrument_tail_idle(engine: MujocoEngine, idle: list[float]) -> None:
    """Record, per `_workers_running` pass, how long the first thread to finish waited for the last."""
    workers_running, step_chunk = engine._workers_running, engine._step_chunk
    ends: dict[int, float] = {}

    def timed_chunk(rows: slice, nstep: int, first: bool, last: bool) -> None:
        step_chunk(rows, nstep, first, last)
        ends[threading.get_ident()] = time.perf_counter()

    @contextmanager
    def timed_pass(nstep: int, first: bool, last: bool) -> Iterator[None]:
        ends.clear()
        with workers_running(nstep, first, last):
            yield
        if len(ends) > 1:
            idle.append(max(ends.values()) - min(ends.values()))

    engine._step_chunk, engine._workers_running = timed_chunk, timed_pass


def _clock_first(engine: MujocoEngine) -> Callable[[], AbstractContextManager[None]]:
    """`engine.stepping` that runs the block (the clock work) before the physics instead of during it."""

    @contextmanager
    def stepping() -> Iterator[None]:
        yield
        with MujocoEngine.stepping(engine):
            pass

    return stepping


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
    serial_stepping = _clock_first(engine)
    one_step = random_action_step(env)
    times: dict[str, list[float]] = defaultdict(list)
    with torch.inference_mode(), torch_threads(1):  # as the bench and a training rollout
        env.reset()
        for i in range(args.steps + 20):
            serial = (i // 2) % 2 == 1
            state, warm = engine.physics_state()
            idle_before = len(idle)
            if serial:
                engine.stepping = serial_stepping
            start = time.perf_counter()
            one_step()
            elapsed = time.perf_counter() - start
            if serial:
                del engine.stepping  # the class's again
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
