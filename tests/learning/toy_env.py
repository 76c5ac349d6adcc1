"""A tiny pure-torch BaseEnv for agent tests: a point in the plane that should reach a target.

obs [N, 6 + extra_obs] = (position, target, target − position, zeros); action [N, 2] = a step in
[−0.2, 0.2]² (clipped here); reward exp(−2·distance²) ∈ (0, 1]; an episode ends with TIME after
`episode_steps` steps or FAIL when the point leaves the [−2, 2]² arena. A policy that walks to the
target scores ≈ 0.8 × episode_steps, one that stands still ≈ 0.3 × episode_steps.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from mimickit.envs.base_env import BaseEnv, BoxSpace, DoneFlags

ACTION_LIMIT = 0.2


class TargetReachEnv(BaseEnv):
    def __init__(self, num_envs: int = 16, episode_steps: int = 20, extra_obs: int = 0, device: str = "cpu") -> None:
        super().__init__(num_envs, device)
        self._episode_steps = episode_steps
        self._extra_obs = extra_obs
        self._pos = torch.zeros(num_envs, 2, device=self.device)
        self._target = torch.zeros(num_envs, 2, device=self.device)
        self._timestep = torch.zeros(num_envs, dtype=torch.long, device=self.device)
        self._obs = torch.zeros(num_envs, 6 + extra_obs, device=self.device)
        self._reward = torch.zeros(num_envs, device=self.device)
        self._done = torch.zeros(num_envs, dtype=torch.long, device=self.device)
        self._info: dict[str, Any] = {"reward_terms": {}, "tracking": {}}
        self.num_steps = 0

    def get_obs_space(self) -> BoxSpace:
        return BoxSpace.unbounded(6 + self._extra_obs)

    def get_action_space(self) -> BoxSpace:
        return BoxSpace(np.full(2, -ACTION_LIMIT, dtype=np.float32), np.full(2, ACTION_LIMIT, dtype=np.float32))

    def reset(self, env_ids: torch.Tensor | None = None) -> tuple[torch.Tensor, dict[str, Any]]:
        ids = torch.arange(self.num_envs, device=self.device) if env_ids is None else env_ids
        n = ids.numel()
        self._pos[ids] = torch.rand(n, 2, device=self.device) * 2.0 - 1.0
        self._target[ids] = torch.rand(n, 2, device=self.device) * 2.0 - 1.0
        self._timestep[ids] = 0
        self._done[ids] = DoneFlags.NULL
        self._update_obs_info()
        return self._obs, self._info

    def step(self, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, dict[str, Any]]:
        self.num_steps += 1
        self._pos += action.clamp(-ACTION_LIMIT, ACTION_LIMIT)
        self._timestep += 1
        self._update_obs_info()
        self._reward[:] = self._info["reward_terms"]["reach"]
        self._done[:] = DoneFlags.NULL
        self._done[self._timestep >= self._episode_steps] = DoneFlags.TIME
        self._done[(self._pos.abs() > 2.0).any(dim=-1)] = DoneFlags.FAIL
        return self._obs, self._reward, self._done, self._info

    def record_diagnostics(self) -> dict[str, float]:
        return {"target_dist": float(torch.linalg.norm(self._target - self._pos, dim=-1).mean())}

    def _update_obs_info(self) -> None:
        diff = self._target - self._pos
        self._obs[:, 0:2] = self._pos
        self._obs[:, 2:4] = self._target
        self._obs[:, 4:6] = diff
        dist = torch.linalg.norm(diff, dim=-1)
        self._info["reward_terms"]["reach"] = torch.exp(-2.0 * dist.square())
        self._info["tracking"]["pos_err"] = dist
