"""The PPO update's speed-ups, each timed in one run against the path it replaced.

One rollout of the DeepMimic CPU agent fills the buffer. Then every variant runs the same update (critic
epochs, then actor epochs, on the same minibatch indices, from the same weights) in alternating rounds:
- `old`: every buffer array gathered per minibatch, observations and actions normalised per minibatch,
  exploring-row masks applied even when every row explored, for-loop SGD (the code before these changes);
- `lazy`: `old` but minibatches gather only the arrays a loss reads;
- `zerograd`: lazy gathers, inputs normalised once, no all-true masks, foreach SGD, gradients zeroed
  before each backward (the update of 2026-12-02), on all torch threads;
- `new`: `zerograd` with gradients set to None before each backward (backward writes them);
- `threads`: `new` as training runs it, under `update_threads()` (torch's ops on one thread, MKL's
  matrix products on all);
- `1thread`: `new` on one torch thread for everything (tried, not kept: MKL partitions some products by
  the thread count, so the weights change);
- `bf16`: `new` under bfloat16 autocast (tried, not kept: it changes the weights).
Prints each variant's seconds per update (median over rounds) and its speed-up over `old`, and whether the
weights each variant ends with equal `old`'s bit for bit.

    python benchmarks/update_paths.py [--num_envs 256] [--rounds 5] [--variants old zerograd new threads]
"""

from __future__ import annotations

import argparse
import copy
import statistics
import time
import types
from collections.abc import Callable
from typing import Any

import torch

from mimickit.envs.env_builder import build_env
from mimickit.learning import rl_util
from mimickit.learning.agent_builder import build_agent
from mimickit.learning.mp_optimizer import MPOptimizer
from mimickit.learning.ppo_agent import PPOAgent
from mimickit.learning.update_threads import update_threads
from mimickit.util.threads import torch_threads

AGENT = "data/agents/deepmimic_humanoid_ppo_cpu_agent.yaml"
ENV = "data/envs/deepmimic_humanoid_env.yaml"
ENGINE = "data/engines/mujoco_engine.yaml"


class EagerBatches:
    """Stand-in for the buffer of the old path: `sample(n)` gathers every array at the buffer's indices."""

    def __init__(self, buffer: Any) -> None:
        self._buffer = buffer

    def sample(self, n: int) -> dict[str, torch.Tensor]:
        batch = self._buffer.sample(n)
        return {name: batch[name] for name in batch}

    def get_sample_count(self) -> int:
        return self._buffer.get_sample_count()


def old_critic_loss(agent: PPOAgent, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    pred = agent._model.eval_critic(agent._obs_norm.normalize(batch["obs"]))
    return {"critic_loss": (batch["tar_val"] - pred).square().mean()}


def old_actor_loss(agent: PPOAgent, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor] | None:
    mask = batch["rand_action_mask"] == 1.0
    if not bool(mask.any()):
        return None
    dist = agent._model.eval_actor(agent._obs_norm.normalize(batch["obs"][mask]))
    a_logp = dist.log_prob(agent._a_norm.normalize(batch["action"][mask]))
    ratio = torch.exp(a_logp - batch["a_logp"][mask])
    clip = agent.config.ppo_clip_ratio
    info = {
        "actor_loss": rl_util.ppo_surrogate_loss(ratio, batch["adv"][mask], clip),
        "clip_frac": rl_util.ppo_clip_frac(ratio.detach(), clip),
        "imp_ratio": ratio.detach().mean(),
    }
    return agent._add_actor_penalties(dist, info)


def run_old(agent: PPOAgent, eager: bool, loop_sgd: bool) -> None:
    """The update as it was: the same minibatch schedule as `PPOAgent._update_model`."""
    saved_buffer = agent._exp_buffer
    if eager:
        agent._exp_buffer = EagerBatches(saved_buffer)  # type: ignore[assignment]
    opts = (agent._critic_optimizer, agent._actor_optimizer)
    if loop_sgd:
        for opt in opts:
            for group in opt._optimizer.param_groups:
                group["foreach"] = False
    orig = (agent._compute_critic_loss, agent._compute_actor_loss)
    agent._compute_critic_loss = lambda b: old_critic_loss(agent, b)  # type: ignore[method-assign]
    agent._compute_actor_loss = lambda b: old_actor_loss(agent, b)  # type: ignore[method-assign]
    try:
        agent._update_model()
    finally:
        agent._exp_buffer = saved_buffer
        agent._compute_critic_loss, agent._compute_actor_loss = orig  # type: ignore[method-assign]
        for opt in opts:
            for group in opt._optimizer.param_groups:
                group["foreach"] = True


def run_bf16(agent: PPOAgent) -> None:
    with torch.autocast("cpu", dtype=torch.bfloat16):
        agent._update_model()


def zeroed_grad_step(opt: MPOptimizer, loss: torch.Tensor) -> None:
    """MPOptimizer.step of one process as it was: gradients zeroed in place, backward adds to them."""
    opt._optimizer.zero_grad(set_to_none=False)
    loss.backward()
    opt._optimizer.step()
    opt._steps += 1


def run_zerograd(agent: PPOAgent) -> None:
    opts = (agent._critic_optimizer, agent._actor_optimizer)
    for opt in opts:
        opt.step = types.MethodType(zeroed_grad_step, opt)  # type: ignore[method-assign]
    try:
        agent._update_model()
    finally:
        for opt in opts:
            del opt.step


def run_in(context: Callable[[], Any]) -> Callable[[PPOAgent], None]:
    def run(agent: PPOAgent) -> None:
        with context():
            agent._update_model()

    return run


VARIANTS: dict[str, Callable[[PPOAgent], None]] = {
    "old": lambda a: run_old(a, eager=True, loop_sgd=True),
    "lazy": lambda a: run_old(a, eager=False, loop_sgd=True),
    "zerograd": run_zerograd,
    "new": lambda a: a._update_model(),
    "threads": run_in(update_threads),
    "1thread": run_in(lambda: torch_threads(1)),
    "bf16": run_bf16,
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--num_envs", type=int, default=256)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--variants", nargs="+", choices=list(VARIANTS), default=list(VARIANTS))
    args = parser.parse_args()
    variants = {name: VARIANTS[name] for name in args.variants}
    if "old" not in variants:
        parser.error("--variants must include old (the figures are relative to it)")
    env = build_env(ENV, ENGINE, args.num_envs, "cpu")
    agent = build_agent(AGENT, env, "cpu", verbose=False)
    agent.start_training()
    agent.train_iteration()  # a first iteration: normalisers and a buffer of real rollout data
    agent._train_iter()  # one more rollout + update, then targets and normalised inputs from the
    agent._build_train_data()  # normalisers as they are now, as an iteration computes them before its update
    start_state = copy.deepcopy(agent._snapshot())
    buffer_state = copy.deepcopy(agent._exp_buffer)
    times: dict[str, list[float]] = {name: [] for name in variants}
    weights: dict[str, dict[str, torch.Tensor]] = {}
    for _ in range(args.rounds):
        for name, variant in variants.items():
            agent._roll_back(copy.deepcopy(start_state))
            agent._exp_buffer = copy.deepcopy(buffer_state)  # same minibatch indices for every variant
            torch.manual_seed(0)
            agent.train()
            start = time.perf_counter()
            variant(agent)
            times[name].append(time.perf_counter() - start)
            weights[name] = {k: v.detach().clone() for k, v in agent.state_dict().items()}
    old = statistics.median(times["old"])
    print(f"PPO update, {args.num_envs} envs, {args.rounds} rounds (median s per update; speed-up over old)")
    for name, ts in times.items():
        same = all(torch.equal(weights["old"][k], v) for k, v in weights[name].items())
        med = statistics.median(ts)
        print(f"  {name:5s} {med:7.3f} s   x{old / med:5.2f}   weights equal old's: {same}")


if __name__ == "__main__":
    main()
