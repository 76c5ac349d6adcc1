"""Proximal Policy Optimisation, as the reference does it.

Per iteration: roll out `steps_per_iter` steps of every env (each env explores with probability
`exp_prob`, else acts with the mean); compute TD(λ) targets and advantages once with the critic and
normaliser as they were before this iteration; then the critic (`critic_epochs` over the buffer in
minibatches of ceil(critic_batch_size × num_envs)), then the actor (clipped surrogate on the
exploring rows + action-bound / entropy / regularisation penalties, and with `lcp_weight` the LCP
penalty: the reference's LCP agent is this class with that weight).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from mimickit.envs.base_env import DoneFlags
from mimickit.learning import mp_util, rl_util
from mimickit.learning.agent_config import PPOAgentConfig
from mimickit.learning.base_agent import AgentMode, BaseAgent
from mimickit.learning.distributions import GaussianDiag
from mimickit.learning.logger import Logger
from mimickit.learning.mp_optimizer import MPOptimizer
from mimickit.learning.ppo_model import PPOModel

LossFn = Callable[[dict[str, torch.Tensor]], "dict[str, torch.Tensor] | None"]


class PPOAgent(BaseAgent):
    config: PPOAgentConfig

    def _build_model(self) -> None:
        self._model = PPOModel(self.config.model, self.get_obs_size(), self.get_action_size())

    def _build_optimizers(self) -> None:
        self._actor_optimizer = MPOptimizer(self.config.actor_optimizer, self._model.get_actor_params())
        self._critic_optimizer = MPOptimizer(self.config.critic_optimizer, self._model.get_critic_params())

    def _optimizers(self) -> dict[str, MPOptimizer]:
        return {"actor": self._actor_optimizer, "critic": self._critic_optimizer}

    def _get_exp_buffer_length(self) -> int:
        return self.config.steps_per_iter

    # ---------------------------------------------------------------- acting

    def _decide_action(self, obs: torch.Tensor, info: dict[str, Any]) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Env action [N, A] plus `a_logp` [N] (of the taken normalised action) and
        `rand_action_mask` [N] (1 where the env sampled, 0 where it took the mean)."""
        dist = self._eval_policy(obs)
        if self._mode == AgentMode.TRAIN:
            num_envs = obs.shape[0]
            prob = torch.full((num_envs,), self._get_exp_prob(), device=obs.device)
            rand_mask = torch.bernoulli(prob)
            norm_a = torch.where(rand_mask.unsqueeze(-1) == 1.0, dist.sample(), dist.mode)
        else:
            norm_a = dist.mode
            rand_mask = torch.zeros(obs.shape[0], device=obs.device)
        a_logp = dist.log_prob(norm_a)
        return self._a_norm.unnormalize(norm_a), {"a_logp": a_logp, "rand_action_mask": rand_mask}

    def _eval_policy(self, obs: torch.Tensor) -> GaussianDiag:
        """The policy of the envs' current observations [N, obs_dim] (ASE adds each env's latent)."""
        return self._model.eval_actor(self._obs_norm.normalize(obs))

    def _record_data_pre_step(
        self, obs: torch.Tensor, info: dict[str, Any], action: torch.Tensor, action_info: dict[str, torch.Tensor]
    ) -> None:
        super()._record_data_pre_step(obs, info, action, action_info)
        for name, val in action_info.items():
            self._exp_buffer.record(name, val)

    def _get_exp_prob(self) -> float:
        cfg = self.config
        if math.isfinite(cfg.exp_anneal_samples):
            lerp = float(np.clip(self._sample_count / cfg.exp_anneal_samples, 0.0, 1.0))
            return (1.0 - lerp) * cfg.exp_prob_beg + lerp * cfg.exp_prob_end
        return cfg.exp_prob_beg

    # ---------------------------------------------------------------- targets

    def _build_train_data(self) -> dict[str, float]:
        """Store `tar_val` (TD(λ) returns) and the actor targets; all [T, N]."""
        self.eval()
        buf = self._exp_buffer
        done = buf.get_data("done")
        with torch.no_grad():
            next_vals = self._eval_critic_batched(buf.get_data("next_obs"))
            next_vals[done == DoneFlags.SUCC] = self._compute_succ_val()
            next_vals[done == DoneFlags.FAIL] = self._compute_fail_val()
            tar_val = rl_util.compute_td_lambda_return(
                buf.get_data("reward"), next_vals, done, self.config.discount, self.config.td_lambda
            )
            adv = tar_val - self._eval_critic_batched(buf.get_data("obs"))
            adv_mean, adv_std = self._calc_adv_stats(adv, buf.get_data("rand_action_mask"))
            norm_adv = (adv - adv_mean) / adv_std.clamp_min(1e-5)
            # The normalisers stay fixed through the updates: normalise their inputs once, not per minibatch.
            buf.set_data("norm_obs", self._obs_norm.normalize(buf.get_data("obs")))
            buf.set_data("norm_action", self._a_norm.normalize(buf.get_data("action")))
        buf.set_data("tar_val", tar_val)
        info = self._store_actor_targets(norm_adv)
        return {"adv_mean": adv_mean.item(), "adv_std": adv_std.item(), **info}

    def _store_actor_targets(self, norm_adv: torch.Tensor) -> dict[str, float]:
        clip = self.config.norm_adv_clip
        self._exp_buffer.set_data("adv", norm_adv.clamp(-clip, clip))
        return {}

    def _calc_adv_stats(self, adv: torch.Tensor, rand_mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Mean and (unbiased) std of the advantages of exploring rows, over all processes."""
        sel = adv[rand_mask == 1.0]
        if sel.numel() == 0:  # nobody explored on this process: fall back to every row
            sel = adv.flatten()
        return mp_util.calc_mean_std(sel)

    def _eval_critic_batched(self, obs: torch.Tensor) -> torch.Tensor:
        """V(normalised obs) for obs [T, N, obs_dim] → [T, N], in chunks of critic_eval_batch_size."""
        flat = obs.reshape(-1, obs.shape[-1])
        chunk = self.config.critic_eval_batch_size or flat.shape[0]
        vals = [self._model.eval_critic(self._obs_norm.normalize(x)) for x in flat.split(chunk)]
        return torch.cat(vals).reshape(obs.shape[:-1])

    # ---------------------------------------------------------------- updates

    def _update_model(self) -> dict[str, float]:
        self.train()
        num_envs = self.get_num_envs()
        num_samples = self._exp_buffer.get_sample_count()
        cfg = self.config
        critic_batch = int(math.ceil(cfg.critic_batch_size * num_envs))
        critic_steps = int(math.ceil(num_samples / critic_batch)) * cfg.critic_epochs
        info = self._run_updates(
            self._critic_optimizer, self._compute_critic_loss, "critic_loss", critic_batch, critic_steps
        )
        actor_batch = int(math.ceil(cfg.actor_batch_size * num_envs))
        actor_steps = int(math.ceil(num_samples / actor_batch)) * cfg.actor_epochs
        actor_loss = self._compute_actor_loss if cfg.lcp_weight == 0 else self._actor_loss_with_lcp
        info.update(self._run_updates(self._actor_optimizer, actor_loss, "actor_loss", actor_batch, actor_steps))
        return info

    def _actor_loss_with_lcp(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor] | None:
        """The agent's actor loss plus `lcp_weight` × the LCP penalty (`rl_util.lcp_penalty`), logged as
        `lcp_loss`. As the reference's LCPAgent: over every row of the minibatch, exploring or not; the
        gradient is taken with respect to the actor's whole input (the observation; ASE's also holds z)."""
        info = self._compute_actor_loss(batch)
        if info is None:
            return None
        lcp = rl_util.lcp_penalty(self._model.eval_actor, self._net_input(batch), batch["norm_action"])
        info["actor_loss"] = info["actor_loss"] + self.config.lcp_weight * lcp
        info["lcp_loss"] = lcp.detach()
        return info

    def _run_updates(
        self, optimizer: MPOptimizer, loss_fn: LossFn, loss_key: str, batch_size: int, steps: int
    ) -> dict[str, float]:
        """`steps` minibatch updates; returns the mean of each logged quantity."""
        sums: dict[str, torch.Tensor] = {}
        done_steps = 0
        for _ in range(steps):
            loss_info = loss_fn(self._exp_buffer.sample(batch_size))
            if loss_info is None:  # no exploring rows in this minibatch
                continue
            optimizer.step(loss_info[loss_key])
            for k, v in loss_info.items():
                sums[k] = sums[k] + v.detach() if k in sums else v.detach()
            done_steps += 1
        return {k: v.item() / done_steps for k, v in sums.items()}

    def _compute_critic_loss(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """mean (R − V(s))², no clipping."""
        pred = self._model.eval_critic(self._net_input(batch))
        return {"critic_loss": (batch["tar_val"] - pred).square().mean()}

    def _net_input(self, batch: dict[str, torch.Tensor], rows: torch.Tensor | None = None) -> torch.Tensor:
        """What the actor and critic read for a minibatch (or its `rows`): the normalised observation.
        Agents that condition on more (ASE's latents) override this one method."""
        return rl_util.select_rows(batch["norm_obs"], rows)

    def _compute_actor_loss(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor] | None:
        """Clipped surrogate on exploring rows, plus the actor penalties (all in `actor_loss`)."""
        rows = rl_util.exploring_rows(batch)
        if rows is not None and not bool(rows.any()):
            return None
        dist = self._model.eval_actor(self._net_input(batch, rows))
        a_logp = dist.log_prob(rl_util.select_rows(batch["norm_action"], rows))
        ratio = torch.exp(a_logp - rl_util.select_rows(batch["a_logp"], rows))
        clip = self.config.ppo_clip_ratio
        info = {
            "actor_loss": rl_util.ppo_surrogate_loss(ratio, rl_util.select_rows(batch["adv"], rows), clip),
            "clip_frac": rl_util.ppo_clip_frac(ratio.detach(), clip),
            "imp_ratio": ratio.detach().mean(),
        }
        return self._add_actor_penalties(dist, info)

    def _add_actor_penalties(self, dist: GaussianDiag, info: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Add the weighted bound / entropy / regularisation terms to info["actor_loss"] (each term
        also logged on its own when its weight is not 0)."""
        cfg = self.config
        loss = info["actor_loss"]
        if cfg.action_bound_weight != 0 and self._action_bounded:
            bound = rl_util.action_bound_loss(dist.mode).mean()
            loss = loss + cfg.action_bound_weight * bound
            info["action_bound_loss"] = bound.detach()
        if cfg.action_entropy_weight != 0:
            entropy = dist.entropy().mean()
            loss = loss - cfg.action_entropy_weight * entropy
            info["action_entropy"] = entropy.detach()
        if cfg.action_reg_weight != 0:
            reg = dist.param_reg().mean()
            loss = loss + cfg.action_reg_weight * reg
            info["action_reg_loss"] = reg.detach()
        info["actor_loss"] = loss
        return info

    def _log_train_info(self, logger: Logger, train_info: dict[str, float], env_diag: dict[str, float]) -> None:
        super()._log_train_info(logger, train_info, env_diag)
        logger.log("Exp_Prob", self._get_exp_prob())
