"""The environment interface every agent talks to (the reference's `BaseEnv`)."""

from __future__ import annotations

import abc
from dataclasses import dataclass
from enum import IntEnum
from typing import Any

import numpy as np
import torch

from mimickit.util.paths import PROJECT_DATA, DataPaths


class DoneFlags(IntEnum):
    NULL = 0
    FAIL = 1
    SUCC = 2
    TIME = 3


class EnvMode(IntEnum):
    TRAIN = 0
    TEST = 1


@dataclass
class BoxSpace:
    """A box of real vectors (what gymnasium's Box is to the reference, without the dependency)."""

    low: np.ndarray
    high: np.ndarray

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(self.low.shape)

    @classmethod
    def unbounded(cls, dim: int) -> BoxSpace:
        return cls(np.full(dim, -np.inf, dtype=np.float32), np.full(dim, np.inf, dtype=np.float32))


class BaseEnv(abc.ABC):
    """N environments stepped together.

    `reset(env_ids)` → (obs [N, obs_dim], info); `step(action [N, act_dim])` → (obs, reward [N],
    done [N] int DoneFlags, info). The returned tensors are the env's own buffers, updated in place by
    later calls: copy what you keep.
    """

    data_paths: DataPaths = PROJECT_DATA  # where its `data/...` files are found (SimEnv takes it as an argument)

    def __init__(self, num_envs: int, device: torch.device | str) -> None:
        self.num_envs = num_envs
        self.device = torch.device(device)
        self._mode = EnvMode.TRAIN

    @abc.abstractmethod
    def reset(self, env_ids: torch.Tensor | None = None) -> tuple[torch.Tensor, dict[str, Any]]: ...

    @abc.abstractmethod
    def step(self, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, dict[str, Any]]: ...

    @abc.abstractmethod
    def get_obs_space(self) -> BoxSpace: ...

    @abc.abstractmethod
    def get_action_space(self) -> BoxSpace: ...

    def set_mode(self, mode: EnvMode) -> None:
        self._mode = mode

    def get_mode(self) -> EnvMode:
        return self._mode

    def get_num_envs(self) -> int:
        return self.num_envs

    def get_reward_fail(self) -> float:
        return 0.0

    def get_reward_succ(self) -> float:
        return 0.0

    def record_diagnostics(self) -> dict[str, float]:
        return {}
