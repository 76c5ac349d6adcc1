"""`mimickit bench --train`: what training keeps of the env's speed, measured in one process.

Rounds alternate, so a load that comes and goes on a shared machine weighs on both figures alike. A round
is two parts on the same env and env count, each starting from a reset of every env:
- env only: `steps_per_iter` control steps with uniform random actions (`mimickit bench`'s step, no network);
- train: one full training iteration of the agent (`BaseAgent.train_iteration`: rollout with the policy,
  targets, every update epoch, normalisers, the divergence check), as `mimickit train` runs it.

train_ratio = train_samples_per_s / env_steps_per_s: the share of the env's own rate that training keeps.
The train part's time is split as the agent records it (metrics.jsonl's `time.*`): sim (env steps), inference
(policy and buffer writes during the rollout), update (targets, updates, normalisers) and other (the
divergence snapshot and check).
"""

from __future__ import annotations

import time
from typing import Any

import torch

from mimickit.envs.env_builder import build_env
from mimickit.learning.agent_builder import build_agent
from mimickit.tools.bench import random_action_step
from mimickit.util.paths import PROJECT_DATA, DataPaths
from mimickit.util.threads import torch_threads

PHASES = ("sim", "inference", "update", "other")


def run_train_bench(
    engine_config: str,
    env_config: str,
    agent_config: str,
    num_envs: int,
    rounds: int = 5,
    warmup: int = 1,
    data_paths: DataPaths = PROJECT_DATA,
) -> dict[str, Any]:
    """`rounds` alternating env-only and train rounds after `warmup` untimed ones (first-call allocations)."""
    env = build_env(env_config, engine_config, num_envs, "cpu", data_paths=data_paths)
    agent = build_agent(agent_config, env, "cpu", verbose=False)
    steps = agent.config.steps_per_iter
    one_step = random_action_step(env)
    env_time, train_time, ratios = 0.0, 0.0, []
    phases = dict.fromkeys(PHASES, 0.0)
    for r in range(warmup + rounds):
        t_env = _env_round(env, one_step, steps)
        agent.start_training()
        start = time.perf_counter()
        step = agent.train_iteration()
        t_train = time.perf_counter() - start
        if step is None:  # only a stop request ends an iteration early; the bench makes none
            raise AssertionError("training iteration interrupted")
        if r < warmup:
            continue
        env_time += t_env
        train_time += t_train
        ratios.append(t_env / t_train)
        timed = {p: step.timing[f"time.{p}_s"] for p in ("sim", "inference", "update")}
        for p, v in timed.items():
            phases[p] += v
        phases["other"] += t_train - sum(timed.values())
    env.engine.close()
    samples = rounds * steps * num_envs
    env_sps, train_sps = samples / env_time, samples / train_time
    return {
        "agent": agent.config.agent_name,
        "agent_config": agent_config,
        "env_config": env_config,
        "num_envs": num_envs,
        "steps_per_iter": steps,
        "rounds": rounds,
        "torch_threads": torch.get_num_threads(),
        "env_steps_per_s": round(env_sps, 1),
        "train_samples_per_s": round(train_sps, 1),
        "train_ratio": round(train_sps / env_sps, 4),
        "train_ratio_per_round": [round(x, 4) for x in ratios],
        "train_split": {p: round(v / train_time, 4) for p, v in phases.items()},
    }


def _env_round(env: Any, one_step: Any, steps: int) -> float:
    """Seconds of `steps` random-action control steps from freshly reset envs."""
    with torch.no_grad(), torch_threads(1):  # as in the training rollout
        env.reset()
        start = time.perf_counter()
        for _ in range(steps):
            one_step()
        return time.perf_counter() - start


def format_train_bench(result: dict[str, Any]) -> str:
    split = result["train_split"]
    return "\n".join(
        [
            f"{result['agent']} ({result['agent_config']}): {result['num_envs']} envs × {result['steps_per_iter']} "
            f"steps, {result['rounds']} rounds, {result['torch_threads']} torch threads",
            f"  env steps/s (random actions)  {result['env_steps_per_s']:>10,.0f}",
            f"  train samples/s               {result['train_samples_per_s']:>10,.0f}",
            f"  train_ratio                   {result['train_ratio']:>10.3f}   per round: "
            + " ".join(f"{r:.2f}" for r in result["train_ratio_per_round"]),
            "  time share of training: " + ", ".join(f"{p} {split[p]:.0%}" for p in PHASES),
        ]
    )
