"""Adversarial Skill Embeddings, as the reference's ASE: AMP whose policy is conditioned on a skill latent z.

* Every env holds a latent z ∈ R^latent_dim, uniform on the unit sphere. It is resampled when the env
  resets and when the env's time reaches the latent's reset time (time at sampling + U[latent_time_min,
  latent_time_max] s), checked after every env step in training and testing. z is recorded per step.
* Actor and critic see [normalised obs, z].
* Reward r = task_reward_weight · r_env + disc_reward_weight · r_disc + enc_reward_weight · r_enc with
  r_enc = max(z·ẑ, 0), ẑ = encoder(normalised disc obs) (unit length), all with the networks and
  normaliser as they were before this iteration's updates.
* Updates: critic, actor (PPO + diversity_weight · diversity loss), discriminator (AMP), then the
  encoder: `enc_epochs` over the rollout in minibatches of ceil(enc_batch_size × num_envs), loss
  mean(−z·ẑ).
* Diversity loss on an actor minibatch's exploring rows (like PPO's surrogate): draw new latents z′ for
  their observations; Δa = mean over action dims of (μ(s,z′) − μ(s,z))², Δz = 0.5 − 0.5 z′·z;
  loss = mean (diversity_tar − Δa / (Δz + 1e-5))².
The latents are not part of the checkpoint (the reference's keys: AMP's plus `_model._enc_layers.*`,
`_model._enc_out.*`). The agent also hands the env its encoder reward, so `info["reward_terms"]`
carries `enc` beside `task` and `disc`.
"""

from __future__ import annotations

import math
from typing import Any, Protocol, runtime_checkable

import torch

from mimickit.envs.base_env import BaseEnv, DoneFlags
from mimickit.learning import ase_util, rl_util
from mimickit.learning.agent_config import ASEAgentConfig
from mimickit.learning.amp_agent import AMPAgent
from mimickit.learning.ase_model import ASEModel
from mimickit.learning.distributions import GaussianDiag
from mimickit.learning.mp_optimizer import MPOptimizer
from mimickit.learning.normalizer import Normalizer
from mimickit.util.errors import MimicKitError


@runtime_checkable
class LatentEnv(Protocol):
    """What ASE needs beyond AMP's env: per-env time (for the latent schedule) and a place to report
    the encoder reward (ASEEnv)."""

    def get_env_time(self, env_ids: torch.Tensor | None = None) -> torch.Tensor: ...

    def set_enc_reward_fn(self, fn: Any, enc_weight: float) -> None: ...


class ASEAgent(AMPAgent):
    config: ASEAgentConfig  # type: ignore[assignment]
    _model: ASEModel

    def __init__(self, config: ASEAgentConfig, env: BaseEnv, device: torch.device | str) -> None:
        if not isinstance(env, LatentEnv):
            raise MimicKitError(
                f"agent ASE needs an env that reports the encoder reward (env_name ase), got {env.__class__.__name__}"
            )
        super().__init__(config, env, device)
        self._latent_env: LatentEnv = env
        n = env.get_num_envs()
        self._schedule = ase_util.LatentSchedule(
            n, config.model.latent_dim, config.latent_time_min, config.latent_time_max, self._device
        )
        self._resample_latents(torch.arange(n, device=self._device))
        env.set_enc_reward_fn(self._enc_reward_for_envs, config.enc_reward_weight)

    # ---------------------------------------------------------------- builders

    def _build_model(self) -> None:
        disc_obs_size = math.prod(self._disc_env.get_disc_obs_space().shape)
        self._model = ASEModel(self.config.model, self.get_obs_size(), self.get_action_size(), disc_obs_size)

    def _build_optimizers(self) -> None:
        super()._build_optimizers()
        self._enc_optimizer = MPOptimizer(self.config.enc_optimizer, self._model.get_enc_params())

    def _optimizers(self) -> dict[str, MPOptimizer]:
        return {**super()._optimizers(), "enc": self._enc_optimizer}

    # ---------------------------------------------------------------- latents

    def get_latents(self) -> torch.Tensor:
        """The envs' current latents [N, latent_dim] (unit length)."""
        return self._schedule.latents

    def _resample_latents(self, env_ids: torch.Tensor) -> None:
        self._schedule.resample(env_ids, self._env_time(env_ids))

    def _env_time(self, env_ids: torch.Tensor) -> torch.Tensor:
        return self._latent_env.get_env_time(env_ids).to(self._device)

    def _latents_for(self, obs: torch.Tensor) -> torch.Tensor:
        """The envs' latents for a batch of their observations; fresh ones for a batch of another size
        (callers of `compute_action` that step their own set of states)."""
        latents = self._schedule.latents
        if obs.shape[0] == latents.shape[0]:
            return latents
        return ase_util.sample_latents(obs.shape[0], self.config.model.latent_dim, obs.device)

    def _reset_envs(self, env_ids: torch.Tensor | None = None) -> tuple[torch.Tensor, dict[str, Any]]:
        out = super()._reset_envs(env_ids)
        ids = torch.arange(self.get_num_envs(), device=self._device) if env_ids is None else env_ids
        self._resample_latents(ids.to(self._device))
        return out

    def _reset_done_envs(
        self, obs: torch.Tensor, info: dict[str, Any], done: torch.Tensor
    ) -> tuple[torch.Tensor, dict[str, Any]]:
        out = super()._reset_done_envs(obs, info, done)  # done envs' time is 0 again
        self._resample_latents((done != DoneFlags.NULL).nonzero().flatten().to(self._device))
        self._schedule.resample_due(self._env_time(torch.arange(self.get_num_envs(), device=self._device)))
        return out

    # ---------------------------------------------------------------- acting and recording

    def _actor_critic_input(self, obs: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        return actor_critic_input(self._obs_norm, obs, z)

    def _eval_policy(self, obs: torch.Tensor) -> GaussianDiag:
        return self._model.eval_actor(self._actor_critic_input(obs, self._latents_for(obs)))

    def _record_data_pre_step(
        self, obs: torch.Tensor, info: dict[str, Any], action: torch.Tensor, action_info: dict[str, torch.Tensor]
    ) -> None:
        super()._record_data_pre_step(obs, info, action, action_info)
        self._exp_buffer.record("latent", self._schedule.latents)

    def _eval_critic_batched(self, obs: torch.Tensor) -> torch.Tensor:
        """V([obs, z]) for the rollout's obs or next_obs [T, N, obs_dim] with each row's latent."""
        latents = self._exp_buffer.get_data("latent")
        flat_obs, flat_z = obs.reshape(-1, obs.shape[-1]), latents.reshape(-1, latents.shape[-1])
        chunk = self.config.critic_eval_batch_size or flat_obs.shape[0]
        vals = [
            self._model.eval_critic(self._actor_critic_input(o, z))
            for o, z in zip(flat_obs.split(chunk), flat_z.split(chunk), strict=True)
        ]
        return torch.cat(vals).reshape(obs.shape[:-1])

    # ---------------------------------------------------------------- rewards

    def _compute_rewards(self) -> dict[str, float]:
        """AMP's task + disc reward, plus the weighted encoder reward, into the stored reward [T, N]."""
        info = super()._compute_rewards()
        buf = self._exp_buffer
        enc_r = self._calc_enc_rewards(self._disc_input_flat(), buf.get_data_flat("latent"))
        reward = buf.get_data("reward")
        buf.set_data("reward", reward + self.config.enc_reward_weight * enc_r.view_as(reward))
        std, mean = torch.std_mean(enc_r)
        return {**info, "enc_reward_mean": mean.item(), "enc_reward_std": std.item()}

    def _calc_enc_rewards(self, disc_obs: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        return calc_enc_rewards(self._model, self._disc_obs_norm, disc_obs, z, self.config.enc_eval_batch_size)

    def _enc_reward_for_envs(self, disc_obs: torch.Tensor, env_ids: torch.Tensor | None) -> torch.Tensor:
        """The env's per-step `enc` term: its disc obs scored against the latents the envs act on."""
        latents = self._schedule.latents
        z = latents if env_ids is None else latents[env_ids.to(self._device)]
        return self._calc_enc_rewards(disc_obs.to(self._device), z)

    # ---------------------------------------------------------------- updates

    def _update_model(self) -> dict[str, float]:
        info = super()._update_model()  # critic, actor, discriminator
        cfg = self.config
        batch = int(math.ceil(cfg.enc_batch_size * self.get_num_envs()))
        steps = int(math.ceil(self._exp_buffer.get_sample_count() / batch)) * cfg.enc_epochs
        info.update(self._run_updates(self._enc_optimizer, self._compute_enc_loss, "enc_loss", batch, steps))
        return info

    def _compute_enc_loss(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        return {"enc_loss": compute_enc_loss(self._model, self._disc_obs_norm, batch["disc_obs"], batch["latent"])}

    def _net_input(self, batch: dict[str, torch.Tensor], rows: torch.Tensor | None = None) -> torch.Tensor:
        if rows is None:
            return self._actor_critic_input(batch["obs"], batch["latent"])
        return self._actor_critic_input(batch["obs"][rows], batch["latent"][rows])

    def _compute_actor_loss(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor] | None:
        """PPO's clipped surrogate and actor penalties on [obs, z], plus diversity_weight × the
        diversity loss, both on the minibatch's exploring rows only (as the reference)."""
        info = super()._compute_actor_loss(batch)  # None when no row explored
        if info is not None and self.config.diversity_weight != 0:
            div = compute_diversity_loss(self._model, self._obs_norm, batch, self.config.diversity_tar)
            info["actor_loss"] = info["actor_loss"] + self.config.diversity_weight * div
            info["diversity_loss"] = div.detach()
        return info


# -------------------------------------------------------------------- the agent's math, on the tensors it needs


def actor_critic_input(obs_norm: Normalizer, obs: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
    """What ASE's actor and critic read: [normalised obs, z]."""
    return torch.cat([obs_norm.normalize(obs), z], dim=-1)


@torch.no_grad()
def calc_enc_rewards(
    model: ASEModel, disc_obs_norm: Normalizer, disc_obs: torch.Tensor, z: torch.Tensor, eval_batch_size: int = 0
) -> torch.Tensor:
    """Unweighted encoder reward [B] of unnormalised disc obs [B, disc_obs_dim] and latents [B, dim],
    in chunks of `eval_batch_size` rows (all at once when it is 0)."""
    norm = disc_obs_norm.normalize(disc_obs)
    chunk = eval_batch_size or max(norm.shape[0], 1)
    pred = torch.cat([model.eval_enc(x) for x in norm.split(chunk)])
    return ase_util.enc_reward(z, pred)


def compute_enc_loss(
    model: ASEModel, disc_obs_norm: Normalizer, disc_obs: torch.Tensor, z: torch.Tensor
) -> torch.Tensor:
    """The encoder's loss mean(−z·ẑ) on unnormalised disc obs [B, disc_obs_dim] and their latents [B, dim]."""
    return ase_util.enc_loss(z, model.eval_enc(disc_obs_norm.normalize(disc_obs)))


def compute_diversity_loss(
    model: ASEModel, obs_norm: Normalizer, batch: dict[str, torch.Tensor], target: float
) -> torch.Tensor:
    """The diversity loss of an actor minibatch's exploring rows (those PPO's surrogate learns from),
    with new latents z′ drawn for them: `ase_util.diversity_loss` of the actor's means under z and z′."""
    rows = rl_util.exploring_rows(batch)
    obs, z = rl_util.select_rows(batch["obs"], rows), rl_util.select_rows(batch["latent"], rows)
    new_z = ase_util.sample_latents(z.shape[0], z.shape[-1], z.device)
    mean_z = model.eval_actor(actor_critic_input(obs_norm, obs, z)).mode
    mean_new_z = model.eval_actor(actor_critic_input(obs_norm, obs, new_z)).mode
    return ase_util.diversity_loss(mean_z, mean_new_z, z, new_z, target)
