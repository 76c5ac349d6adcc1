"""ASE's latent sampling, encoder reward / loss and diversity loss (as the reference's ASE), as pure functions."""

from __future__ import annotations

import torch

DIVERSITY_EPS = 1e-5
"""Added to the latent distance so two identical latents do not divide by zero."""


def sample_latents(n: int, dim: int, device: torch.device | str = "cpu") -> torch.Tensor:
    """n latents [n, dim] uniform on the unit sphere (normalised Gaussians)."""
    z = torch.randn(n, dim, device=device)
    return torch.nn.functional.normalize(z, dim=-1)


def enc_reward(z: torch.Tensor, enc_pred: torch.Tensor) -> torch.Tensor:
    """r_enc = max(z·ẑ, 0), [B, dim] × [B, dim] → [B]: how well the encoder recovers the latent."""
    return torch.clamp_min((z * enc_pred).sum(-1), 0.0)


def enc_loss(z: torch.Tensor, enc_pred: torch.Tensor) -> torch.Tensor:
    """mean(−z·ẑ): the encoder learns to point its prediction at the latent that was acted on."""
    return -(z * enc_pred).sum(-1).mean()


def diversity_loss(
    mean_z: torch.Tensor, mean_new_z: torch.Tensor, z: torch.Tensor, new_z: torch.Tensor, target: float
) -> torch.Tensor:
    """mean (target − Δa / (Δz + 1e-5))² with Δa = mean over action dims of (μ(s,z′) − μ(s,z))² and
    Δz = 0.5 − 0.5·z′·z (0 for the same latent, 1 for opposite ones): different latents should give
    actions that differ in proportion. mean_* [B, A] (normalised action means), z / new_z [B, dim]."""
    delta_a = (mean_new_z - mean_z).square().mean(-1)
    delta_z = 0.5 - 0.5 * (new_z * z).sum(-1)
    return (target - delta_a / (delta_z + DIVERSITY_EPS)).square().mean()


class LatentSchedule:
    """Each env's latent z [N, dim] (unit length) and the env time at which it is due for a new one:
    a latent drawn at env time t is kept until t + U[time_min, time_max] s."""

    def __init__(self, num_envs: int, dim: int, time_min: float, time_max: float, device: torch.device) -> None:
        self._time_min, self._time_max = time_min, time_max
        self._device = device
        self._latents = torch.zeros(num_envs, dim, device=device)
        self._reset_time = torch.zeros(num_envs, device=device)

    @property
    def latents(self) -> torch.Tensor:
        return self._latents

    @property
    def reset_time(self) -> torch.Tensor:
        """The env time [N] at which each env's latent is resampled."""
        return self._reset_time

    def resample(self, env_ids: torch.Tensor, env_time: torch.Tensor) -> None:
        """New latents for env_ids, whose env times are env_time [len(env_ids)]."""
        n = len(env_ids)
        if n == 0:
            return
        self._latents[env_ids] = sample_latents(n, self._latents.shape[-1], self._device)
        hold = torch.empty(n, device=self._device).uniform_(self._time_min, self._time_max)
        self._reset_time[env_ids] = env_time + hold

    def resample_due(self, env_time: torch.Tensor) -> None:
        """Resample the latents whose hold time has run out at every env's time env_time [N]."""
        ids = (env_time >= self._reset_time).nonzero().flatten()
        self.resample(ids, env_time[ids])
