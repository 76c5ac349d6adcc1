"""ASEEnv (the reference's `ase`): AMPEnv whose resets sometimes start from the default pose.

After the reference-state init, each reset env independently, with probability `default_reset_prob`,
is put back into the character's init pose with zero velocities (CharEnv's reset). Its disc-obs
history is still the clip leading up to the sampled motion time, as the reference does it, so the
first discriminator observations of such an episode join a clip history to a standing pose.

The latent skill codes z live in the ASE agent (`learning/ase_agent.py`), which samples them per env and resamples
them on reset and on its own schedule. The env only scores them: with an encoder reward function
attached (`set_enc_reward_fn`), `info["reward_terms"]` holds `enc` beside AMP's `task` and `disc`.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from mimickit.envs.amp_env import AMPEnv
from mimickit.envs.char_env import CharEnv
from mimickit.envs.env_config import ASEEnvConfig

EncRewardFn = Callable[[torch.Tensor, torch.Tensor | None], torch.Tensor]
"""(disc obs [n, disc_obs_dim], env ids [n] or None for all envs) → unweighted encoder reward [n]."""


class ASEEnv(AMPEnv):
    config: ASEEnvConfig  # type: ignore[assignment]

    def _build_sim_tensors(self, config: ASEEnvConfig) -> None:  # type: ignore[override]
        super()._build_sim_tensors(config)
        self._enc_reward_fn: EncRewardFn | None = None
        self._enc_reward_weight = 0.0

    # ---------------------------------------------------------------- public
    def set_enc_reward_fn(self, fn: EncRewardFn | None, enc_weight: float = 1.0) -> None:
        """Score every step's disc obs (with the agent's latents) into `info["reward_terms"]["enc"]`."""
        self._enc_reward_fn = fn
        self._enc_reward_weight = enc_weight
        self._info.pop("reward_terms", None)  # rebuilt with the new set of terms at the next update

    @property
    def reward_weights(self) -> dict[str, float]:
        weights = dict(self._reward_weights)
        if self._enc_reward_fn is not None:
            weights["enc"] = self._enc_reward_weight
        return weights

    # ---------------------------------------------------------------- resets
    def _reset_char(self, env_ids: torch.Tensor) -> None:
        super()._reset_char(env_ids)  # RSI: also picks the motion and time the disc history comes from
        p = self.config.default_reset_prob
        if p <= 0 or len(env_ids) == 0:
            return
        to_default = torch.rand(len(env_ids), device=self.device) < p
        default_ids = env_ids[to_default]
        if len(default_ids) > 0:
            CharEnv._reset_char(self, default_ids)

    # ---------------------------------------------------------------- rewards
    def _store_reward_terms(self, disc_input: torch.Tensor, env_ids: torch.Tensor | None) -> None:
        """AMP's `task` and `disc`, plus `enc` from the attached encoder reward function."""
        terms = {"task": self._compute_task_reward(env_ids)}
        if self._disc_reward_fn is not None:
            terms["disc"] = self._disc_reward_fn(disc_input)
        if self._enc_reward_fn is not None:
            terms["enc"] = self._enc_reward_fn(disc_input, env_ids)
        self._store_info("reward_terms", terms, env_ids)
