"""Adversarial Motion Priors, as the reference's AMP: PPO whose reward comes from a discriminator.

Per iteration, after PPO's rollout (which also records the env's disc obs of every step, post-step):
1. fetch as many demo disc obs from the clips as the rollout holds (`disc_obs_demo`);
2. push agent disc obs into the replay buffer (all of them until it is full, then a random
   `disc_replay_samples` subset);
3. reward r = task_reward_weight · r_env + disc_reward_weight · r_disc with
   r_disc = −log(max(1 − sigmoid(D), 1e-4)) · disc_reward_scale, using the discriminator and
   normaliser as they were before this iteration's updates; then PPO's targets;
4. critic and actor updates (PPO), then `disc_epochs` over the rollout in minibatches of
   ceil(disc_batch_size × num_envs) (agent, demo) samples plus as many replayed agent samples: BCE
   (agent 0, demo 1) + gradient penalty + logit regularisation; weight decay through the optimiser.
The agent also hands its discriminator to the env (`set_disc_reward_fn`), so `info["reward_terms"]`
carries the per-step style reward (`disc`) beside the task reward (`task`) for metrics and viewers.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Protocol, runtime_checkable

import torch

from mimickit.envs.base_env import BaseEnv, BoxSpace
from mimickit.learning import disc_util
from mimickit.learning.agent_config import AMPAgentConfig
from mimickit.learning.amp_model import AMPModel
from mimickit.learning.experience_buffer import ExperienceBuffer
from mimickit.learning.mp_optimizer import MPOptimizer
from mimickit.learning.normalizer import DiffNormalizer, Normalizer
from mimickit.learning.ppo_agent import PPOAgent
from mimickit.util.errors import MimicKitError

_DISC_OBS_CLIP = 10.0


@runtime_checkable
class DiscObsEnv(Protocol):
    """What AMP needs of an env beyond `BaseEnv` (AMPEnv and its subclasses provide it)."""

    def get_disc_obs_space(self) -> BoxSpace: ...

    def fetch_disc_obs_demo(self, num_samples: int) -> torch.Tensor: ...

    def set_disc_reward_fn(
        self, fn: Callable[[torch.Tensor], torch.Tensor] | None, task_weight: float, disc_weight: float
    ) -> None: ...


class AMPAgent(PPOAgent):
    config: AMPAgentConfig  # type: ignore[assignment]

    def __init__(self, config: AMPAgentConfig, env: BaseEnv, device: torch.device | str) -> None:
        super().__init__(config, env, device)
        # Batch 1: the replay buffer is a flat ring of single samples.
        self._disc_buffer = ExperienceBuffer(config.disc_buffer_size, 1, self._device)
        self._disc_env.set_disc_reward_fn(self._calc_disc_rewards, config.task_reward_weight, config.disc_reward_weight)

    # ---------------------------------------------------------------- builders

    def _build_normalizers(self) -> None:
        super()._build_normalizers()
        if not isinstance(self._env, DiscObsEnv):
            raise MimicKitError(
                "agent AMP needs an env with a discriminator observation (env_name amp), "
                f"got {self._env.__class__.__name__}"
            )
        self._disc_env: DiscObsEnv = self._env
        self._disc_obs_norm = self._build_disc_obs_norm(self._disc_env.get_disc_obs_space().shape)

    def _build_disc_obs_norm(self, shape: tuple[int, ...]) -> Normalizer | DiffNormalizer:
        return Normalizer(shape, device=self._device, clip=_DISC_OBS_CLIP)

    def _build_model(self) -> None:
        disc_obs_size = math.prod(self._disc_env.get_disc_obs_space().shape)
        self._model = AMPModel(self.config.model, self.get_obs_size(), self.get_action_size(), disc_obs_size)

    def _build_optimizers(self) -> None:
        super()._build_optimizers()
        self._disc_optimizer = MPOptimizer(self.config.disc_optimizer, self._model.get_disc_params())

    def _optimizers(self) -> dict[str, MPOptimizer]:
        return {**super()._optimizers(), "disc": self._disc_optimizer}

    # ---------------------------------------------------------------- rollout data

    def _record_data_post_step(
        self, next_obs: torch.Tensor, reward: torch.Tensor, done: torch.Tensor, info: dict
    ) -> None:
        super()._record_data_post_step(next_obs, reward, done, info)
        disc_obs = info["disc_obs"]  # after the step, before done envs are reset
        self._exp_buffer.record("disc_obs", disc_obs)
        if self._need_normalizer_update():
            self._disc_obs_norm.record(disc_obs)

    def _update_normalizers(self) -> None:
        super()._update_normalizers()
        self._disc_obs_norm.update()

    def _build_train_data(self) -> dict[str, float]:
        self._record_disc_demo_data()
        self._store_disc_replay_data()
        reward_info = self._compute_rewards()
        return {**super()._build_train_data(), **reward_info}

    def _record_disc_demo_data(self) -> None:
        """Fresh demo disc obs, one per rollout sample (unrelated to the rollout row it sits beside)."""
        n = self._exp_buffer.get_data_flat("disc_obs").shape[0]
        demo = self._disc_env.fetch_disc_obs_demo(n)
        self._exp_buffer.set_data_flat("disc_obs_demo", demo)
        # The reference records demos even after the normaliser froze; unused sums, so only while open.
        if self._need_normalizer_update():
            self._disc_obs_norm.record(demo)

    def _disc_input_flat(self) -> torch.Tensor:
        """The rollout's discriminator inputs before normalisation [T·N, disc_obs_dim] (AMP: disc obs)."""
        return self._exp_buffer.get_data_flat("disc_obs")

    def _store_disc_replay_data(self) -> None:
        store_disc_replay(self._disc_buffer, self._disc_input_flat(), self.config.disc_replay_samples)

    def _compute_rewards(self) -> dict[str, float]:
        """Replace the stored env reward [T, N] by the weighted task + discriminator reward."""
        buf, cfg = self._exp_buffer, self.config
        task_r = buf.get_data("reward")
        disc_r = self._calc_disc_rewards(self._disc_input_flat()).view_as(task_r)
        reward, info = style_rewards(task_r, disc_r, cfg.task_reward_weight, cfg.disc_reward_weight)
        buf.set_data("reward", reward)
        return info

    def _calc_disc_rewards(self, disc_obs: torch.Tensor) -> torch.Tensor:
        """Unweighted discriminator reward [B] of unnormalised disc inputs [B, disc_obs_dim] (ADD: differences)."""
        cfg = self.config
        return calc_disc_rewards(
            self._model, self._disc_obs_norm, disc_obs, cfg.disc_reward_scale, cfg.disc_eval_batch_size
        )

    # ---------------------------------------------------------------- updates

    def _update_model(self) -> dict[str, float]:
        info = super()._update_model()
        cfg = self.config
        batch = int(math.ceil(cfg.disc_batch_size * self.get_num_envs()))
        steps = int(math.ceil(self._exp_buffer.get_sample_count() / batch)) * cfg.disc_epochs
        info.update(self._run_updates(self._disc_optimizer, self._compute_disc_loss, "disc_loss", batch, steps))
        return info

    def _compute_disc_loss(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """AMP's discriminator loss on a minibatch and as many replayed agent samples."""
        agent_obs = batch["disc_obs"]
        replay = self._disc_buffer.sample(agent_obs.shape[0])["disc_obs"]
        cfg = self.config
        return compute_disc_loss(
            self._model,
            self._disc_obs_norm,
            torch.cat([agent_obs, replay]),
            batch["disc_obs_demo"],
            cfg.disc_logit_reg,
            cfg.disc_grad_penalty,
        )


# -------------------------------------------------------------------- the agent's math, on the tensors it needs


def store_disc_replay(buffer: ExperienceBuffer, disc_input: torch.Tensor, replay_samples: int) -> None:
    """Push a rollout's discriminator inputs [B, D] into the replay ring (batch 1): all of them until
    it is full, then a random `replay_samples` subset."""
    n = disc_input.shape[0]
    full = buffer.get_total_samples() >= buffer.capacity
    num = min(n, replay_samples) if full else n
    idx = torch.randperm(n, device=disc_input.device)[:num]
    buffer.push({"disc_obs": disc_input[idx].unsqueeze(1)})


def style_rewards(
    task_reward: torch.Tensor, disc_reward: torch.Tensor, task_weight: float, disc_weight: float
) -> tuple[torch.Tensor, dict[str, float]]:
    """The training reward task_weight · r_task + disc_weight · r_disc (same shape), and the disc
    reward's `disc_reward_mean` / `disc_reward_std` for the metrics."""
    std, mean = torch.std_mean(disc_reward)
    reward = task_weight * task_reward + disc_weight * disc_reward
    return reward, {"disc_reward_mean": mean.item(), "disc_reward_std": std.item()}


@torch.no_grad()
def calc_disc_rewards(
    model: AMPModel,
    disc_obs_norm: Normalizer | DiffNormalizer,
    disc_input: torch.Tensor,
    reward_scale: float,
    eval_batch_size: int = 0,
) -> torch.Tensor:
    """Unweighted discriminator reward [B] of unnormalised disc inputs [B, D], in chunks of
    `eval_batch_size` rows (all at once when it is 0)."""
    norm = disc_obs_norm.normalize(disc_input)
    chunk = eval_batch_size or max(norm.shape[0], 1)
    logits = torch.cat([model.eval_disc(x) for x in norm.split(chunk)])
    return disc_util.disc_reward(logits, reward_scale)


def compute_disc_loss(
    model: AMPModel,
    disc_obs_norm: Normalizer,
    agent_obs: torch.Tensor,
    demo_obs: torch.Tensor,
    logit_reg: float,
    grad_penalty: float,
) -> dict[str, torch.Tensor]:
    """BCE (agent 0, demo 1) + grad_penalty · gradient penalty + logit_reg · logit regulariser on
    unnormalised agent (rollout and replayed) and demo disc obs; gradients are taken w.r.t. the
    normalised inputs. `disc_loss` is what the optimiser minimises; the rest is logged."""
    norm_agent = disc_obs_norm.normalize(agent_obs).requires_grad_(True)
    norm_demo = disc_obs_norm.normalize(demo_obs).requires_grad_(True)
    agent_logit = model.eval_disc(norm_agent)
    demo_logit = model.eval_disc(norm_demo)

    loss = disc_util.disc_bce_loss(agent_logit, demo_logit)
    penalty = 0.5 * (
        disc_util.disc_grad_penalty(demo_logit, norm_demo) + disc_util.disc_grad_penalty(agent_logit, norm_agent)
    )
    loss = loss + grad_penalty * penalty
    agent_acc, demo_acc = disc_util.disc_accuracy(agent_logit.detach(), demo_logit.detach())
    info = {
        "disc_grad_penalty": penalty.detach(),
        "disc_agent_acc": agent_acc,
        "disc_demo_acc": demo_acc,
        "disc_agent_logit": agent_logit.detach().mean(),
        "disc_demo_logit": demo_logit.detach().mean(),
    }
    if logit_reg != 0:
        logit_loss = disc_util.disc_logit_reg(model.get_disc_logit_weights())
        loss = loss + logit_reg * logit_loss
        info["disc_logit_loss"] = logit_loss.detach()
    return {"disc_loss": loss, **info}
