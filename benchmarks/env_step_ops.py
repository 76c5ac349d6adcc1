"""Torch ops per env step of the bench loop (random actions, done envs reset), by the torch profiler
(figures, not tests).

    python benchmarks/env_step_ops.py [--num_envs 256] [--steps 20] [--top 15] [--by_part]

Counts the top-level aten ops (those not called from inside another aten op) per control step, step
and resets together, and lists the most frequent; `--by_part` also splits them by the env method they
run in (the innermost of PARTS; DeepMimic's methods as they are named now). Run it from another
source tree (cwd) to count that tree's env: its code comes first on sys.path.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import sys

sys.path.insert(0, os.getcwd())

import torch  # noqa: E402
from torch.profiler import ProfilerActivity, profile, record_function  # noqa: E402

from mimickit.envs.env_builder import build_env  # noqa: E402
from mimickit.tools.bench import random_action_step  # noqa: E402

PARTS = (
    "_apply_action", "_step_physics", "_advance_clock", "_update_misc", "_compute_obs", "_update_info",
    "_store_info", "_update_reward", "_update_done", "_reset_envs",
)  # fmt: skip


def _label_parts(env: object) -> None:
    """Wrap each of PARTS the env has in a profiler range named after it."""
    for name in PARTS:
        method = getattr(env, name, None)
        if method is None:
            continue

        def wrapped(*args: object, _method=method, _name=name, **kwargs: object) -> object:
            with record_function("part:" + _name):
                return _method(*args, **kwargs)

        setattr(env, name, wrapped)


def _part_of(event: object) -> str:
    parent = event.cpu_parent
    while parent is not None:
        if parent.name.startswith("part:"):
            return parent.name[5:]
        parent = parent.cpu_parent
    return "other"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--engine_config", default="data/engines/mujoco_engine.yaml")
    ap.add_argument("--env_config", default="data/envs/deepmimic_humanoid_env.yaml")
    ap.add_argument("--num_envs", type=int, default=256)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--top", type=int, default=15)
    ap.add_argument("--by_part", action="store_true")
    args = ap.parse_args()
    env = build_env(args.env_config, args.engine_config, args.num_envs, "cpu")
    if args.by_part:
        _label_parts(env)
    one_step = random_action_step(env)
    with torch.inference_mode():
        env.reset()
        for _ in range(10):
            one_step()
        with profile(activities=[ProfilerActivity.CPU]) as prof:
            for _ in range(args.steps):
                one_step()
    top_level = [
        e
        for e in prof.events()
        if e.name.startswith("aten::") and (e.cpu_parent is None or not e.cpu_parent.name.startswith("aten::"))
    ]
    counts = collections.Counter(e.name for e in top_level)
    result = {
        "num_envs": args.num_envs,
        "ops_per_step": round(len(top_level) / args.steps, 1),
        "top": {k: round(v / args.steps, 1) for k, v in counts.most_common(args.top)},
    }
    if args.by_part:
        parts = collections.Counter(_part_of(e) for e in top_level)
        result["by_part"] = {k: round(v / args.steps, 1) for k, v in parts.most_common()}
    print(json.dumps(result))


if __name__ == "__main__":
    main()
