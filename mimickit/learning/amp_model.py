"""AMP's networks, as the reference's: PPO's actor and critic plus a discriminator.

Discriminator: `_disc_layers` (a named MLP) → `_disc_logits` (Linear → 1, weights U(-1, 1), zero
bias), on normalised disc obs [B, disc_obs_dim]. Attribute names are the reference's checkpoint keys.
"""

from __future__ import annotations

from collections.abc import Iterator

import torch
from torch import nn

from mimickit.learning.agent_config import AMPModelConfig
from mimickit.learning.nets import build_net
from mimickit.learning.ppo_model import PPOModel

DISC_LOGIT_INIT_SCALE = 1.0


class AMPModel(PPOModel):
    def __init__(self, config: AMPModelConfig, obs_size: int, action_size: int, disc_obs_size: int) -> None:
        super().__init__(config, obs_size, action_size)
        self._disc_layers, disc_out = build_net(config.disc_net, disc_obs_size)
        self._disc_logits = nn.Linear(disc_out, 1)
        nn.init.uniform_(self._disc_logits.weight, -DISC_LOGIT_INIT_SCALE, DISC_LOGIT_INIT_SCALE)
        nn.init.zeros_(self._disc_logits.bias)

    def eval_disc(self, norm_disc_obs: torch.Tensor) -> torch.Tensor:
        """Logits [B] for normalised disc obs [B, disc_obs_dim] (> 0: looks like a demo)."""
        return self._disc_logits(self._disc_layers(norm_disc_obs)).squeeze(-1)

    def get_disc_logit_weights(self) -> torch.Tensor:
        """The logit layer's weights, flattened (what the logit regulariser penalises)."""
        return self._disc_logits.weight.flatten()

    def get_disc_params(self) -> Iterator[nn.Parameter]:
        yield from self._disc_layers.parameters()
        yield from self._disc_logits.parameters()
