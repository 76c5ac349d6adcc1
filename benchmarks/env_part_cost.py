"""What one part of the env step costs inside the real bench loop, on the MuJoCo engine (figures, not tests).

    python benchmarks/env_part_cost.py PART [PART ...] [--num_envs 256] [--steps 240]

A part timed alone runs with hot caches and without the physics beside it; inside the loop it can cost
twice as much. So this runs the bench loop (random actions, done envs reset) in
alternating 3-step blocks where the part runs once or twice (the second call repeats the same work, so
the results stay right) and prints, per part, the median step time of both kinds of block and their
difference: the part's marginal cost per control step. Both kinds share one process and one time window,
which a machine whose speed drifts needs for differences of 1-3%. A part that is not doubled gives the
noise floor (`none`).

Parts: none, gather_refresh (engine), kinematics (engine, per env), info (reward terms, tracking errors and
their state reads), obs, done.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections.abc import Callable

import torch

from mimickit.engines import mujoco_engine
from mimickit.envs.env_builder import build_env
from mimickit.tools.bench import random_action_step

PARTS = ("none", "gather_refresh", "kinematics", "info", "obs", "done")


def _doubled(f: Callable, on: list[bool]) -> Callable:
    """f, called twice while on[0] is set (the second call's result is returned)."""

    def g(*args, **kwargs):
        if on[0]:
            f(*args, **kwargs)
        return f(*args, **kwargs)

    return g


def _double_part(env, part: str, on: list[bool]) -> None:
    engine = env.engine
    targets = {
        "none": [],
        "gather_refresh": [(engine, "_gather"), (engine, "_refresh")],
        "kinematics": [(mujoco_engine, "_update_kinematics")],
        "info": [(env, "_update_info")],
        "obs": [(env, "_compute_obs")],
        "done": [(env, "_update_done")],
    }[part]
    for owner, name in targets:
        setattr(owner, name, _doubled(getattr(owner, name), on))


def measure(part: str, engine_config: str, env_config: str, num_envs: int, steps: int) -> dict[str, float]:
    env = build_env(env_config, engine_config, num_envs, "cpu")
    on = [False]
    kinematics = mujoco_engine._update_kinematics
    _double_part(env, part, on)
    one_step = random_action_step(env)
    times: dict[bool, list[float]] = {False: [], True: []}
    try:
        with torch.inference_mode():
            env.reset()
            for i in range(steps + 30):
                on[0] = (i // 3) % 2 == 1
                start = time.perf_counter()
                one_step()
                if i >= 30 and i % 3 != 0:  # the first step of a block may still feel the previous kind
                    times[on[0]].append(time.perf_counter() - start)
    finally:
        mujoco_engine._update_kinematics = kinematics
        env.engine.close()
    once, twice = (statistics.median(times[k]) * 1e3 for k in (False, True))
    return {"part": part, "once_ms": round(once, 3), "twice_ms": round(twice, 3), "marginal_ms": round(twice - once, 3)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("parts", nargs="+", choices=PARTS)
    ap.add_argument("--engine_config", default="data/engines/mujoco_engine.yaml")
    ap.add_argument("--env_config", default="data/envs/deepmimic_humanoid_env.yaml")
    ap.add_argument("--num_envs", type=int, default=256)
    ap.add_argument("--steps", type=int, default=240)
    args = ap.parse_args()
    for part in args.parts:
        print(json.dumps({"num_envs": args.num_envs, **measure(part, args.engine_config, args.env_config,
                                                                args.num_envs, args.steps)}))  # fmt: skip


if __name__ == "__main__":
    main()
