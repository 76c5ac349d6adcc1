"""Advantage-Weighted Regression, as the reference's AWR: PPO's rollout, critic and targets; a different actor loss.

Actor targets: a_weight = min(exp(Â / awr_temp), a_weight_clip) with the normalised advantage Â
*not* clipped; actor loss = −mean(a_weight · log π(a|s)) over exploring rows, plus the same
bound / entropy / regularisation penalties as PPO. No log-probabilities are stored.
"""

from __future__ import annotations

from typing import Any

import torch

from mimickit.learning import rl_util
from mimickit.learning.agent_config import AWRAgentConfig
from mimickit.learning.ppo_agent import PPOAgent


class AWRAgent(PPOAgent):
    config: AWRAgentConfig  # type: ignore[assignment]

    def _decide_action(self, obs: torch.Tensor, info: dict[str, Any]) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        action, action_info = super()._decide_action(obs, info)
        action_info.pop("a_logp")
        return action, action_info

    def _store_actor_targets(self, norm_adv: torch.Tensor) -> dict[str, float]:
        a_weight = rl_util.awr_weights(norm_adv, self.config.awr_temp, self.config.a_weight_clip)
        self._exp_buffer.set_data("a_weight", a_weight)
        return {
            "a_weight_mean": a_weight.mean().item(),
            "a_weight_min": a_weight.min().item(),
            "a_weight_max": a_weight.max().item(),
        }

    def _compute_actor_loss(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor] | None:
        rows = rl_util.exploring_rows(batch)
        if rows is not None and not bool(rows.any()):
            return None
        dist = self._model.eval_actor(self._net_input(batch, rows))
        a_logp = dist.log_prob(rl_util.select_rows(batch["norm_action"], rows))
        info = {"actor_loss": -(rl_util.select_rows(batch["a_weight"], rows) * a_logp).mean()}
        return self._add_actor_penalties(dist, info)
