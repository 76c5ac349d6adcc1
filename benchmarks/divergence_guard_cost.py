"""What the divergence guard adds to a training iteration: the snapshot (copies of the weights,
normalisers and optimiser states, so a diverged iteration can be undone) and the non-finite check of
the rollout, losses, gradient and weights, each timed against whole iterations of the same agent.

    python benchmarks/divergence_guard_cost.py --num_envs 256 --iters 3
    python benchmarks/divergence_guard_cost.py --arg_file args/deepmimic_humanoid_ppo_args.txt --device cuda:0

Prints one JSON object: median seconds of an iteration, of a snapshot and of a check, and the guard's
share of the iteration.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mimickit.learning.agent_builder import build_agent  # noqa: E402
from mimickit.runner.inputs import RunInputs, build_run_env  # noqa: E402
from mimickit.util.arg_parser import ArgParser  # noqa: E402
from mimickit.util.paths import PROJECT_DATA  # noqa: E402


def _median_s(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--arg_file", default="args/deepmimic_humanoid_demo_ppo_args.txt")
    p.add_argument("--num_envs", type=int, default=256)
    p.add_argument("--iters", type=int, default=3, help="training iterations timed")
    p.add_argument("--repeats", type=int, default=20, help="snapshots and checks timed")
    p.add_argument("--device", default="cpu")
    opts = p.parse_args()

    args = ArgParser()
    args.load_args(["--arg_file", str(ROOT / opts.arg_file)])
    path = lambda key: str(PROJECT_DATA.resolve(args.parse_string(key))) if args.parse_string(key) else None  # noqa: E731
    inputs = RunInputs(path("env_config") or "", path("engine_config"), path("agent_config"), None)
    env, _ = build_run_env(inputs, opts.num_envs, opts.device)
    agent = build_agent(inputs.agent_file, env, opts.device, verbose=False)
    agent._curr_obs, agent._curr_info = agent._reset_envs()
    agent._init_train()

    def one_iter() -> None:
        info = agent._train_iter()
        assert info is not None and agent._non_finite is None

    one_iter()  # warm-up: buffers and optimiser states exist from here on
    iteration = _median_s(one_iter, opts.iters)
    snapshot = _median_s(agent._snapshot, opts.repeats)
    check = _median_s(lambda: agent._first_non_finite({}, {}), opts.repeats)
    print(json.dumps({
        "arg_file": opts.arg_file, "num_envs": opts.num_envs, "device": opts.device,
        "params": agent.get_num_params(), "iteration_s": iteration, "snapshot_s": snapshot, "check_s": check,
        "guard_share_of_iteration": (snapshot + check) / iteration,
    }))  # fmt: skip


if __name__ == "__main__":
    main()
