"""Adversarial Differential Discriminators, as the reference's ADD: AMP whose discriminator judges differences.

Each rollout row holds the env's ADD disc obs of the character right after the step (`disc_obs`) and
the same features of the reference at the same env's motion time (`disc_obs_demo`); the
discriminator's input is their difference Δ = demo − agent, scaled per dimension by the running mean
|Δ| (`DiffNormalizer`, no centring). A perfect imitation is Δ = 0, so the single positive sample is
the zero vector and every rollout / replayed difference is a negative:

    loss = 0.5 · (BCE(D(0), 1) + BCE(D(Δ ∪ Δ_replay), 0))
         + disc_logit_reg · ‖w_logit‖² + disc_grad_penalty · 0.5 · (mean ‖∇D(Δ)‖² + ‖∇D(0)‖²)

with gradients taken w.r.t. the normalised inputs; weight decay through the disc optimiser, as AMP.
Reward r_disc = −log(max(1 − sigmoid(D(norm Δ)), 1e-4)) · disc_reward_scale, before this iteration's
updates. The replay buffer holds differences (under AMP's key `disc_obs`). Logged: disc_loss,
disc_grad_penalty, disc_logit_loss, disc_pos_acc / disc_neg_acc (demo: D(0) > 0 / agent: D(Δ) < 0),
disc_pos_logit / disc_neg_logit, disc_reward_mean / std.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import torch

from mimickit.envs.base_env import BaseEnv
from mimickit.learning import disc_util
from mimickit.learning.agent_config import ADDAgentConfig
from mimickit.learning.amp_agent import AMPAgent
from mimickit.learning.amp_model import AMPModel
from mimickit.learning.normalizer import DiffNormalizer
from mimickit.learning.ppo_agent import PPOAgent
from mimickit.util.errors import MimicKitError


@runtime_checkable
class DiffDiscObsEnv(Protocol):
    """What ADD needs beyond AMP's env: the reference's disc obs at every env's motion time (ADDEnv)."""

    def get_disc_obs_demo(self) -> torch.Tensor: ...


class ADDAgent(AMPAgent):
    config: ADDAgentConfig  # type: ignore[assignment]

    def __init__(self, config: ADDAgentConfig, env: BaseEnv, device: torch.device | str) -> None:
        if not isinstance(env, DiffDiscObsEnv):
            raise MimicKitError(
                "agent ADD needs an env with reference disc obs at each env's motion time (env_name add), "
                f"got {env.__class__.__name__}"
            )
        super().__init__(config, env, device)

    def _build_disc_obs_norm(self, shape: tuple[int, ...]) -> DiffNormalizer:
        return DiffNormalizer(shape, device=self._device)

    # ---------------------------------------------------------------- rollout data

    def _record_data_post_step(
        self, next_obs: torch.Tensor, reward: torch.Tensor, done: torch.Tensor, info: dict[str, Any]
    ) -> None:
        PPOAgent._record_data_post_step(self, next_obs, reward, done, info)
        # Both after the step and before done envs are reset: a per-env tracking difference.
        self._exp_buffer.record("disc_obs", info["disc_obs"])
        self._exp_buffer.record("disc_obs_demo", info["disc_obs_demo"])
        if self._need_normalizer_update():
            self._disc_obs_norm.record(disc_input(info["disc_obs"], info["disc_obs_demo"]))

    def _build_train_data(self) -> dict[str, float]:
        # No demo fetch (AMP's first step): the env already paired every row with its reference.
        self._store_disc_replay_data()
        reward_info = self._compute_rewards()
        return {**PPOAgent._build_train_data(self), **reward_info}

    def _disc_input_flat(self) -> torch.Tensor:
        buf = self._exp_buffer
        return disc_input(buf.get_data_flat("disc_obs"), buf.get_data_flat("disc_obs_demo"))

    # ---------------------------------------------------------------- updates

    def _compute_disc_loss(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """ADD's discriminator loss on a minibatch's differences and as many replayed ones."""
        diff = disc_input(batch["disc_obs"], batch["disc_obs_demo"])
        replay = self._disc_buffer.sample(diff.shape[0])["disc_obs"]
        cfg = self.config
        return compute_disc_loss(
            self._model, self._disc_obs_norm, torch.cat([diff, replay]), cfg.disc_logit_reg, cfg.disc_grad_penalty
        )


# -------------------------------------------------------------------- the agent's math, on the tensors it needs


def disc_input(disc_obs: torch.Tensor, disc_obs_demo: torch.Tensor) -> torch.Tensor:
    """What ADD's discriminator judges: Δ = reference − agent, before normalisation."""
    return disc_obs_demo - disc_obs


def compute_disc_loss(
    model: AMPModel, disc_obs_norm: DiffNormalizer, diffs: torch.Tensor, logit_reg: float, grad_penalty: float
) -> dict[str, torch.Tensor]:
    """BCE of the zero difference (positive) against `diffs` [B, D] (unnormalised rollout and replayed
    differences, the negatives), plus the penalties; `disc_loss` is what the optimiser minimises."""
    norm_neg = disc_obs_norm.normalize(diffs).requires_grad_(True)
    # Zero normalised is zero: the positive goes in as is.
    pos = torch.zeros(1, diffs.shape[-1], device=diffs.device, requires_grad=True)
    neg_logit = model.eval_disc(norm_neg)
    pos_logit = model.eval_disc(pos)

    bce = disc_util.disc_bce_loss(neg_logit, pos_logit)
    logit_loss = disc_util.disc_logit_reg(model.get_disc_logit_weights())
    penalty = 0.5 * (disc_util.disc_grad_penalty(neg_logit, norm_neg) + disc_util.disc_grad_penalty(pos_logit, pos))
    loss = bce + logit_reg * logit_loss + grad_penalty * penalty
    neg_acc, pos_acc = disc_util.disc_accuracy(neg_logit.detach(), pos_logit.detach())
    return {
        "disc_loss": loss,
        "disc_grad_penalty": penalty.detach(),
        "disc_logit_loss": logit_loss.detach(),
        "disc_pos_acc": pos_acc,
        "disc_neg_acc": neg_acc,
        "disc_pos_logit": pos_logit.detach().mean(),
        "disc_neg_logit": neg_logit.detach().mean(),
    }
