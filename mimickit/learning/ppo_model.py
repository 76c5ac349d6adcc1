"""Actor and critic networks of PPO and AWR, as the reference's (its checkpoint keys).

Actor: `_actor_layers` (a named MLP) → `_action_dist` (Gaussian head: `_mean_net`, `_logstd_net`).
Critic: `_critic_layers` → `_critic_out` (Linear → 1, PyTorch default weights, zero bias).
The attribute names are the checkpoint key names of the reference, so its `.pt` files load strictly.
Both take normalised observations [B, obs_dim].
"""

from __future__ import annotations

from collections.abc import Iterator

import torch
from torch import nn

from mimickit.learning.agent_config import ActorCriticModelConfig
from mimickit.learning.distributions import GaussianDiag, GaussianDiagHead
from mimickit.learning.nets import build_net


class PPOModel(nn.Module):
    def __init__(self, config: ActorCriticModelConfig, obs_size: int, action_size: int) -> None:
        super().__init__()
        self._actor_layers, actor_out = build_net(config.actor_net, obs_size)
        self._action_dist = GaussianDiagHead(
            actor_out, action_size, config.actor_std_type, config.action_std, config.actor_init_output_scale
        )
        self._critic_layers, critic_out = build_net(config.critic_net, obs_size)
        self._critic_out = nn.Linear(critic_out, 1)
        nn.init.zeros_(self._critic_out.bias)

    def eval_actor(self, norm_obs: torch.Tensor) -> GaussianDiag:
        """Policy over normalised actions for normalised observations [B, obs_dim]."""
        return self._action_dist(self._actor_layers(norm_obs))

    def eval_critic(self, norm_obs: torch.Tensor) -> torch.Tensor:
        """State values [B] for normalised observations [B, obs_dim]."""
        return self._critic_out(self._critic_layers(norm_obs)).squeeze(-1)

    def get_actor_params(self) -> Iterator[nn.Parameter]:
        yield from self._actor_layers.parameters()
        yield from self._action_dist.parameters()

    def get_critic_params(self) -> Iterator[nn.Parameter]:
        yield from self._critic_layers.parameters()
        yield from self._critic_out.parameters()
