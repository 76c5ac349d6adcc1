"""Pure functions of the PPO/AWR math (the reference's), testable on hand-made tensors."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

import torch

from mimickit.envs.base_env import DoneFlags

if TYPE_CHECKING:
    from mimickit.learning.distributions import GaussianDiag


def compute_td_lambda_return(
    reward: torch.Tensor,
    next_val: torch.Tensor,
    done: torch.Tensor,
    discount: float,
    td_lambda: float,
) -> torch.Tensor:
    """TD(λ) returns of a rollout, [T, N].

    reward, next_val (V of the row's next observation, already replaced by the succ/fail value where
    the episode ended that way) and done (DoneFlags) are [T, N]. Backwards over rows:
    R_{T−1} = r_{T−1} + γ V'_{T−1};  R_t = r_t + γ [(1 − λ_t) V'_t + λ_t R_{t+1}],
    λ_t = λ·[done_t = NULL]: an episode end cuts the λ chain (TIME bootstraps from V').
    """
    num_steps = reward.shape[0]
    lam = td_lambda * (done == DoneFlags.NULL).to(reward.dtype)
    ret = torch.zeros_like(reward)
    ret[-1] = reward[-1] + discount * next_val[-1]
    for t in range(num_steps - 2, -1, -1):
        ret[t] = reward[t] + discount * ((1.0 - lam[t]) * next_val[t] + lam[t] * ret[t + 1])
    return ret


def ppo_surrogate_loss(ratio: torch.Tensor, adv: torch.Tensor, clip_ratio: float) -> torch.Tensor:
    """−mean(min(A·ρ, A·clip(ρ, 1−ε, 1+ε))); ratio ρ and adv A are [B]. Returns a 0-d tensor."""
    clipped = ratio.clamp(1.0 - clip_ratio, 1.0 + clip_ratio)
    return -torch.minimum(adv * ratio, adv * clipped).mean()


def ppo_clip_frac(ratio: torch.Tensor, clip_ratio: float) -> torch.Tensor:
    """Fraction of samples whose ratio lies outside [1−ε, 1+ε], 0-d."""
    return ((ratio - 1.0).abs() > clip_ratio).to(ratio.dtype).mean()


def action_bound_loss(norm_mean: torch.Tensor) -> torch.Tensor:
    """Σ_dims [min(μ+1, 0)² + max(μ−1, 0)²] of the policy mean in normalised units [B, A] → [B]."""
    below = (norm_mean + 1.0).clamp_max(0.0)
    above = (norm_mean - 1.0).clamp_min(0.0)
    return (below.square() + above.square()).sum(dim=-1)


def lcp_penalty(
    eval_actor: Callable[[torch.Tensor], GaussianDiag], norm_input: torch.Tensor, norm_action: torch.Tensor
) -> torch.Tensor:
    """Lipschitz-constrained policies' penalty: the mean over rows of ‖∇ₓ log π(a|x)‖², x the actor's
    normalised input, a the normalised action taken. Built with `create_graph` so that the actor's
    optimiser steps through it (a gradient of a gradient)."""
    x = norm_input.detach().requires_grad_(True)
    logp = eval_actor(x).log_prob(norm_action)
    (grad,) = torch.autograd.grad(logp.sum(), x, create_graph=True)
    return grad.square().sum(dim=-1).mean()


def awr_weights(norm_adv: torch.Tensor, temp: float, weight_clip: float) -> torch.Tensor:
    """min(exp(Â / temp), clip), same shape as the (unclipped) normalised advantages."""
    return torch.exp(norm_adv / temp).clamp_max(weight_clip)


def exploring_rows(batch: Mapping[str, torch.Tensor]) -> torch.Tensor | None:
    """The mask of a minibatch's exploring rows (the actor learns from these only); None when every row
    explored (exp_prob 1, the usual case), which spares the losses a masked copy of each input."""
    mask = batch["rand_action_mask"] == 1.0
    return None if bool(mask.all()) else mask


def select_rows(x: torch.Tensor, rows: torch.Tensor | None) -> torch.Tensor:
    """`x[rows]`, or `x` itself when `rows` is None (all rows)."""
    return x if rows is None else x[rows]
