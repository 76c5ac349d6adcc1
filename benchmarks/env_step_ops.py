"""Torch ops per env step of the bench loop (random actions, done envs reset), by the torch profiler
(figures, not tests).

    python benchmarks/env_step_ops.py [--num_envs 256] [--steps 20] [--top 15]

Counts the top-level aten ops (those not called from inside another aten op) per control step, step
and resets together, and lists the most frequent. Run it from another source tree (cwd) to count that
tree's env: its code comes first on sys.path.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import sys

sys.path.insert(0, os.getcwd())

import torch  # noqa: E402
from torch.profiler import ProfilerActivity, profile  # noqa: E402

from mimickit.envs.env_builder import build_env  # noqa: E402
from mimickit.tools.bench import random_action_step  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--engine_config", default="data/engines/mujoco_engine.yaml")
    ap.add_argument("--env_config", default="data/envs/deepmimic_humanoid_env.yaml")
    ap.add_argument("--num_envs", type=int, default=256)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--top", type=int, default=15)
    args = ap.parse_args()
    env = build_env(args.env_config, args.engine_config, args.num_envs, "cpu")
    one_step = random_action_step(env)
    with torch.inference_mode():
        env.reset()
        for _ in range(10):
            one_step()
        with profile(activities=[ProfilerActivity.CPU]) as prof:
            for _ in range(args.steps):
                one_step()
    top_level = [
        e.name
        for e in prof.events()
        if e.name.startswith("aten::") and (e.cpu_parent is None or not e.cpu_parent.name.startswith("aten::"))
    ]
    counts = collections.Counter(top_level)
    print(
        json.dumps(
            {
                "num_envs": args.num_envs,
                "ops_per_step": round(len(top_level) / args.steps, 1),
                "top": {k: round(v / args.steps, 1) for k, v in counts.most_common(args.top)},
            }
        )
    )


if __name__ == "__main__":
    main()
