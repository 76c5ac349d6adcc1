"""Undiscounted episode returns and lengths of N envs, as the reference's return tracker.

`update(reward, done)` adds each env's reward to its running return; envs whose done flag is not NULL fold
their episode into the running means and start over. Episodes that end in FAIL are also counted: a clip that
does not loop ends its episodes early as a success, so a short mean length alone is no fall. Everything stays
on the device (no host sync per step); the getters convert to python numbers.
"""

from __future__ import annotations

import torch

from mimickit.envs.base_env import DoneFlags


class ReturnTracker:
    def __init__(self, num_envs: int, device: torch.device | str) -> None:
        self._device = torch.device(device)
        self._return_buf = torch.zeros(num_envs, dtype=torch.float64, device=self._device)
        self._ep_len_buf = torch.zeros(num_envs, dtype=torch.long, device=self._device)
        self._eps_per_env = torch.zeros(num_envs, dtype=torch.long, device=self._device)
        self._return_sum = torch.zeros((), dtype=torch.float64, device=self._device)
        self._ep_len_sum = torch.zeros((), dtype=torch.float64, device=self._device)
        self._fail_count = torch.zeros((), dtype=torch.long, device=self._device)

    def reset(self) -> None:
        """Forget finished episodes and in-flight returns."""
        for buf in (
            self._return_buf, self._ep_len_buf, self._eps_per_env, self._return_sum, self._ep_len_sum, self._fail_count
        ):  # fmt: skip
            buf.zero_()

    def update(self, reward: torch.Tensor, done: torch.Tensor) -> None:
        """reward [N] float, done [N] int DoneFlags of one env step."""
        self._return_buf += reward
        self._ep_len_buf += 1
        finished = done != DoneFlags.NULL
        self._return_sum += torch.where(finished, self._return_buf, 0.0).sum()
        self._ep_len_sum += torch.where(finished, self._ep_len_buf, 0).sum()
        self._eps_per_env += finished.long()
        self._fail_count += (done == DoneFlags.FAIL).sum()
        self._return_buf.masked_fill_(finished, 0.0)
        self._ep_len_buf.masked_fill_(finished, 0)

    def get_episodes(self) -> int:
        """Episodes finished since the last reset."""
        return int(self._eps_per_env.sum().item())

    def get_failed_episodes(self) -> int:
        """Finished episodes that ended in FAIL (a fall, early termination) since the last reset."""
        return int(self._fail_count.item())

    def get_eps_per_env(self) -> torch.Tensor:
        """Finished episodes per env [N] (long)."""
        return self._eps_per_env

    def get_mean_return(self) -> float:
        return float(self._return_sum.item()) / max(self.get_episodes(), 1)

    def get_mean_ep_len(self) -> float:
        return float(self._ep_len_sum.item()) / max(self.get_episodes(), 1)
