"""ASE's networks, as the reference's: AMP's actor, critic and discriminator plus an encoder.

Actor and critic take [normalised obs, z] (obs_size + latent_dim inputs). The encoder `_enc_layers`
(a named MLP on the normalised disc obs) → `_enc_out` (Linear → latent_dim; weights U(−0.1, 0.1) and
bias 0, as in the reference) predicts the latent that produced a disc obs; its output is scaled to unit
length, like the latents themselves, so z·ẑ is a cosine in [-1, 1]. Attribute names are the
reference's checkpoint keys.
"""

from __future__ import annotations

from collections.abc import Iterator

import torch
import torch.nn.functional as F
from torch import nn

from mimickit.learning.agent_config import ASEModelConfig
from mimickit.learning.amp_model import AMPModel
from mimickit.learning.nets import build_net

ENC_OUT_INIT_SCALE = 0.1  # `_enc_out` weights ~ U(−0.1, 0.1), bias 0 (the reference's enc_logit_init_scale)


class ASEModel(AMPModel):
    def __init__(self, config: ASEModelConfig, obs_size: int, action_size: int, disc_obs_size: int) -> None:
        super().__init__(config, obs_size + config.latent_dim, action_size, disc_obs_size)
        self._enc_layers, enc_out = build_net(config.enc_net, disc_obs_size)
        self._enc_out = nn.Linear(enc_out, config.latent_dim)
        # The reference's init, not PyTorch's U(±1/√fan_in): the starting encoder matters to ASE's
        # reward, so a faithful run starts where the reference's does.
        nn.init.uniform_(self._enc_out.weight, -ENC_OUT_INIT_SCALE, ENC_OUT_INIT_SCALE)
        nn.init.zeros_(self._enc_out.bias)

    def eval_enc(self, norm_disc_obs: torch.Tensor) -> torch.Tensor:
        """Unit-length latent predictions [B, latent_dim] for normalised disc obs [B, disc_obs_dim]."""
        return F.normalize(self._enc_out(self._enc_layers(norm_disc_obs)), dim=-1)

    def get_enc_params(self) -> Iterator[nn.Parameter]:
        yield from self._enc_layers.parameters()
        yield from self._enc_out.parameters()
