"""How far the training update is from this machine's matrix-product speed, and what train_ratio that allows.

`mimickit bench --train` splits an iteration into sim, inference and update. This asks whether the update
can still shrink without changing what is computed. In one process:
1. the floating-point operations of one training iteration, counted by torch (`FlopCounterMode`), less those
   of the rollout's policy evaluations (the same count for `steps_per_iter` calls of `compute_action`): the
   update's FLOPs (critic values for the targets, every critic and actor minibatch, forward and backward);
2. rounds alternating the env alone (random actions), one training iteration (its `time.*` split), and the
   update's own matrix shapes multiplied on all threads (the fastest fp32 GEMM rate here, as MKL reaches
   it on those shapes), and the same in bfloat16 (what a bf16 update could reach; it changes the weights);
3. the bound: the train_ratio if the update ran at that GEMM rate with no other cost, sim and inference as
   measured; and the GEMM rate the update would need for a target ratio.

    python benchmarks/update_roofline.py [--num_envs 256] [--rounds 3] [--target 0.70]
        [--agent_config data/agents/amp_humanoid_cpu_agent.yaml --env_config data/envs/amp_humanoid_env.yaml]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from typing import Any

import torch
from torch.utils.flop_counter import FlopCounterMode

from mimickit.envs.env_builder import build_env
from mimickit.learning.agent_builder import build_agent
from mimickit.tools.bench import random_action_step
from mimickit.util.threads import torch_threads

ENGINE = "data/engines/mujoco_engine.yaml"


def count_flops(fn: Any) -> int:
    with FlopCounterMode(display=False) as counter:
        fn()
    return int(counter.get_total_flops())


def linear_shapes(agent: torch.nn.Module, batch: int) -> list[tuple[int, int, int]]:
    """(m, k, n) of each Linear layer's forward product at `batch` rows."""
    return [(batch, m.in_features, m.out_features) for m in agent.modules() if isinstance(m, torch.nn.Linear)]


def gemm_seconds(
    shapes: list[tuple[int, int, int]], dtype: torch.dtype = torch.float32, reps: int = 20
) -> tuple[float, int]:
    """Seconds for `reps` passes over the forward products and the two backward products of each shape,
    and their FLOPs: the update's matrix work at the library's best on this machine, in `dtype`."""
    mats = []
    for m, k, n in shapes:
        x, w, g = (torch.randn(*s).to(dtype) for s in ((m, k), (k, n), (m, n)))
        mats.append((x, w, g))
    flops = sum(3 * 2 * m * k * n for m, k, n in shapes) * reps

    def run() -> None:
        for x, w, g in mats:
            x @ w  # forward
            g @ w.T  # gradient of the input
            x.T @ g  # gradient of the weight

    run()
    start = time.perf_counter()
    for _ in range(reps):
        run()
    return time.perf_counter() - start, flops


def env_seconds(env: Any, steps: int) -> float:
    one_step = random_action_step(env)
    with torch.no_grad(), torch_threads(1):
        env.reset()
        start = time.perf_counter()
        for _ in range(steps):
            one_step()
        return time.perf_counter() - start


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--env_config", default="data/envs/deepmimic_humanoid_env.yaml")
    p.add_argument("--agent_config", default="data/agents/deepmimic_humanoid_ppo_cpu_agent.yaml")
    p.add_argument("--num_envs", type=int, default=256)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--target", type=float, default=0.70)
    p.add_argument("--json", action="store_true")
    a = p.parse_args()
    env = build_env(a.env_config, ENGINE, a.num_envs, "cpu")
    agent = build_agent(a.agent_config, env, "cpu", verbose=False)
    steps = agent.config.steps_per_iter
    agent.start_training()
    agent.train_iteration()  # warm-up (first-call allocations)
    try:
        total = count_flops(agent.train_iteration)
    except RuntimeError as e:  # torch's counter cannot follow autograd.grad (AMP's gradient penalty)
        raise SystemExit(f"torch's FLOP counter failed on {a.agent_config}'s iteration: {e}") from None
    obs, _ = env.reset()
    with torch.no_grad():
        rollout = steps * count_flops(lambda: agent.compute_action(obs, deterministic=False))
    update_flops = total - rollout
    shapes = linear_shapes(agent, 1024)
    rows: list[dict[str, float]] = []
    for _ in range(a.rounds):
        t_env = env_seconds(env, steps)
        t = agent.train_iteration().timing
        t_gemm, gemm_flops = gemm_seconds(shapes)
        t_bf16, _ = gemm_seconds(shapes, torch.bfloat16)
        phases = {k: t[f"time.{k}_s"] for k in ("sim", "inference", "update")}
        rows.append({"env": t_env, **phases, "gemm": gemm_flops / t_gemm, "gemm_bf16": gemm_flops / t_bf16})
    med = {k: statistics.median(r[k] for r in rows) for k in rows[0]}
    print(json.dumps(report(med, update_flops, a.target, steps * a.num_envs), indent=None if a.json else 2))


def report(med: dict[str, float], update_flops: int, target: float, samples: int) -> dict[str, Any]:
    gemm = med["gemm"]
    update_at_peak = update_flops / gemm
    train_now = med["sim"] + med["inference"] + med["update"]
    needed_update = med["env"] / target - med["sim"] - med["inference"]
    return {
        "samples_per_iter": samples,
        "update_gflop_per_iter": round(update_flops / 1e9, 2),
        "update_s": round(med["update"], 3),
        "update_gflop_per_s": round(update_flops / med["update"] / 1e9, 1),
        "gemm_gflop_per_s_at_update_shapes": round(gemm / 1e9, 1),
        "update_share_of_gemm_peak": round(update_at_peak / med["update"], 3),
        "bf16_gemm_gflop_per_s_at_update_shapes": round(med["gemm_bf16"] / 1e9, 1),
        "env_only_s": round(med["env"], 3),
        "sim_s": round(med["sim"], 3),
        "inference_s": round(med["inference"], 3),
        "train_ratio_now": round(med["env"] / train_now, 3),
        "train_ratio_if_update_at_gemm_peak": round(med["env"] / (med["sim"] + med["inference"] + update_at_peak), 3),
        "train_ratio_if_update_at_bf16_gemm_peak": round(
            med["env"] / (med["sim"] + med["inference"] + update_flops / med["gemm_bf16"]), 3
        ),
        "target": target,
        "update_s_needed_for_target": round(needed_update, 3),
        "gflop_per_s_needed_for_target": round(update_flops / needed_update / 1e9, 1) if needed_update > 0 else None,
    }


if __name__ == "__main__":
    main()
