"""Discriminator losses and reward of adversarial imitation (the reference's AMP), as pure functions.

Logits are [B] (one per sample); inputs are the *normalised* disc obs [B, disc_obs_dim].
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

DISC_REWARD_MIN_PROB = 1e-4
"""1 − sigmoid(logit) is clamped to at least this, so a fooled discriminator gives a finite reward."""


def disc_reward(logit: torch.Tensor, scale: float) -> torch.Tensor:
    """r = −log(max(1 − sigmoid(logit), 1e-4)) · scale, [B] → [B]: ≈ 0 for samples the discriminator
    is sure are the agent's, large for samples it takes for demos."""
    prob = torch.sigmoid(logit)
    return -torch.log(torch.clamp_min(1.0 - prob, DISC_REWARD_MIN_PROB)) * scale


def disc_bce_loss(agent_logit: torch.Tensor, demo_logit: torch.Tensor) -> torch.Tensor:
    """0.5 · (BCE(agent, label 0) + BCE(demo, label 1)), each term a mean over its own samples."""
    agent_loss = F.binary_cross_entropy_with_logits(agent_logit, torch.zeros_like(agent_logit))
    demo_loss = F.binary_cross_entropy_with_logits(demo_logit, torch.ones_like(demo_logit))
    return 0.5 * (agent_loss + demo_loss)


def disc_grad_penalty(logit: torch.Tensor, norm_input: torch.Tensor) -> torch.Tensor:
    """mean over samples of ‖∂logit/∂input‖², differentiable (the penalty itself is optimised).
    `norm_input` [B, D] must require grad and `logit` [B] be computed from it."""
    (grad,) = torch.autograd.grad(logit, norm_input, grad_outputs=torch.ones_like(logit), create_graph=True)
    return grad.square().sum(-1).mean()


def disc_logit_reg(logit_weights: torch.Tensor) -> torch.Tensor:
    """Σ w² of the logit layer's weights (bias excluded)."""
    return logit_weights.square().sum()


def disc_accuracy(agent_logit: torch.Tensor, demo_logit: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(fraction of agent samples with logit < 0, fraction of demo samples with logit > 0)."""
    return (agent_logit < 0).float().mean(), (demo_logit > 0).float().mean()
