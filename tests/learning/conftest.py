"""Agent configs sized for the toy env: a small net and Adam so a few iterations show learning."""

from __future__ import annotations

from typing import Any

import pytest
import torch

from mimickit.learning.base_agent import AgentMode


def ppo_config_dict(**overrides: Any) -> dict[str, Any]:
    cfg: dict[str, Any] = {
        "agent_name": "PPO",
        "model": {
            "actor_net": "fc_2layers_128units",
            "actor_init_output_scale": 0.01,
            "actor_std_type": "FIXED",
            "action_std": 0.3,
            "critic_net": "fc_2layers_128units",
        },
        "actor_optimizer": {"type": "Adam", "learning_rate": "1e-3"},
        "critic_optimizer": {"type": "Adam", "learning_rate": "3e-3"},
        "discount": 0.9,
        "steps_per_iter": 20,
        "iters_per_output": 5,
        "test_episodes": 16,
        "normalizer_samples": 1e8,
        "actor_epochs": 5,
        "actor_batch_size": 4,
        "critic_epochs": 5,
        "critic_batch_size": 4,
        "td_lambda": 0.95,
        "ppo_clip_ratio": 0.2,
        "norm_adv_clip": 4.0,
        "action_bound_weight": 10.0,
        "action_entropy_weight": 0.0,
        "action_reg_weight": 0.0,
    }
    cfg.update(overrides)
    return cfg


def disc_config_dict(agent_name: str, disc_grad_penalty: float) -> dict[str, Any]:
    """A small AMP or ADD config for the toy envs: PPO's, a 2x128 discriminator, SGD, tiny buffers."""
    cfg = ppo_config_dict(agent_name=agent_name, steps_per_iter=8, iters_per_output=2, test_episodes=0)
    cfg["model"] = dict(cfg["model"], disc_net="fc_2layers_128units")
    cfg.update(
        disc_optimizer={"type": "SGD", "learning_rate": 2.5e-4, "weight_decay": 1e-4},
        disc_epochs=2, disc_batch_size=2, disc_buffer_size=100, disc_replay_samples=5, disc_logit_reg=0.01,
        disc_grad_penalty=disc_grad_penalty, disc_reward_scale=2.0, task_reward_weight=0.0, disc_reward_weight=1.0,
    )  # fmt: skip
    return cfg


def awr_config_dict(**overrides: Any) -> dict[str, Any]:
    cfg = ppo_config_dict(agent_name="AWR", awr_temp=1.0, a_weight_clip=20.0)
    del cfg["ppo_clip_ratio"], cfg["norm_adv_clip"]
    cfg.update(overrides)
    return cfg


@pytest.fixture(autouse=True)
def _seed_and_threads():
    torch.manual_seed(0)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # tiny nets: threads only add overhead on the shared 2-core machine
    yield
    torch.set_num_threads(threads)


def first_step_info(env: Any, agent: Any, seed: int = 5) -> dict[str, Any]:
    """The info of one deterministic (test-mode) step from a reset drawn with `seed`: two agents with the
    same weights on envs of one config give the same one."""
    agent.set_mode(AgentMode.TEST)
    torch.manual_seed(seed)
    obs, _ = env.reset()
    return env.step(agent.compute_action(obs))[3]
