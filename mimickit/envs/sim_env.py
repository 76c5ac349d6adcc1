"""SimEnv: an environment backed by a physics engine (the reference's `SimEnv`).

Construction order: engine → `_build_envs` (characters, objects, motions) → `initialize_sim` →
action space → sim tensors → data buffers (reward, done, timestep, time, observation).
"""

from __future__ import annotations

import abc
from typing import Any

import torch

from mimickit.engines.engine import Engine, EngineConfig
from mimickit.engines.engine_builder import build_engine
from mimickit.envs.base_env import BaseEnv, BoxSpace, DoneFlags, EnvMode
from mimickit.envs.env_config import SimEnvConfig
from mimickit.util.paths import PROJECT_DATA, DataPaths
from mimickit.util.timer import PhaseTimer


class SimEnv(BaseEnv):
    def __init__(
        self,
        env_config: SimEnvConfig,
        engine_config: EngineConfig,
        num_envs: int,
        device: torch.device | str = "cpu",
        visualize: bool = False,
        data_paths: DataPaths = PROJECT_DATA,
    ) -> None:
        super().__init__(num_envs, device)
        self.data_paths = data_paths  # where the configs' `data/...` files are found
        self.profiler = PhaseTimer()
        self.config = env_config
        self.engine_config = engine_config
        self._visualize = visualize
        self._episode_length = env_config.episode_length
        self._engine = self._build_engine(engine_config, num_envs, visualize)
        self._build_envs(env_config, num_envs)
        self._engine.initialize_sim()
        self._action_space = self._build_action_space()
        self._build_sim_tensors(env_config)
        self._build_data_buffers()

    # ----------------------------------------------------------- construction
    def _build_engine(self, engine_config: EngineConfig, num_envs: int, visualize: bool) -> Engine:
        return build_engine(engine_config, num_envs, self.device, visualize)

    @abc.abstractmethod
    def _build_envs(self, config: SimEnvConfig, num_envs: int) -> None: ...

    @abc.abstractmethod
    def _build_action_space(self) -> BoxSpace: ...

    def _build_sim_tensors(self, config: SimEnvConfig) -> None:
        pass

    def _build_data_buffers(self) -> None:
        n, dev = self.num_envs, self.device
        self._reward_buf = torch.zeros(n, device=dev)
        self._done_buf = torch.zeros(n, dtype=torch.long, device=dev)
        self._timestep_buf = torch.zeros(n, dtype=torch.long, device=dev)
        self._time_buf = torch.zeros(n, device=dev)
        self._info: dict[str, Any] = {}
        obs = self._compute_obs()
        self._obs_buf = torch.zeros_like(obs)
        self._obs_space = BoxSpace.unbounded(obs.shape[-1])

    # ---------------------------------------------------------------- public
    @property
    def engine(self) -> Engine:
        return self._engine

    def get_obs_space(self) -> BoxSpace:
        return self._obs_space

    def get_action_space(self) -> BoxSpace:
        return self._action_space

    def get_env_time(self, env_ids: torch.Tensor | None = None) -> torch.Tensor:
        return self._time_buf if env_ids is None else self._time_buf[env_ids]

    def get_visualize(self) -> bool:
        return self._visualize

    def set_mode(self, mode: EnvMode) -> None:
        super().set_mode(mode)

    def compute_obs(self, env_ids: torch.Tensor) -> torch.Tensor:
        """The observation [n, obs_dim] of `env_ids` computed afresh from the current state (not the
        buffer that reset and step return)."""
        return self._compute_obs(env_ids)

    def reset(self, env_ids: torch.Tensor | None = None) -> tuple[torch.Tensor, dict[str, Any]]:
        if env_ids is None:
            env_ids = torch.arange(self.num_envs, device=self.device)
        elif env_ids.dtype == torch.bool:
            env_ids = torch.nonzero(env_ids).flatten()
        elif env_ids.dtype != torch.long or env_ids.dim() != 1:  # the envs index with index_select: 1-D long
            env_ids = env_ids.to(torch.long).reshape(-1)
        if len(env_ids) > 0:
            with self.profiler.phase("reset"):
                self._reset_envs(env_ids)
                self._obs_buf.index_copy_(0, env_ids, self._compute_obs(env_ids))
                self._update_info(env_ids)
        return self._obs_buf, self._info

    def step(self, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, dict[str, Any]]:
        """One control step. The env sets no torch thread count: its caller picks the phase's (the agents'
        rollouts, `mimickit bench` and the studio run it on one thread, see `util.threads`)."""
        with self.profiler.phase("action"):
            self._apply_action(action)
        with self.profiler.phase("physics"):
            self._step_physics()
        with self.profiler.phase("task"):
            self._update_misc()
        with self.profiler.phase("observation"):
            self._obs_buf[:] = self._compute_obs()
        with self.profiler.phase("reward_done"):
            self._update_info()
            self._update_reward()
            self._update_done()
        return self._obs_buf, self._reward_buf, self._done_buf, self._info

    # ------------------------------------------------------------- internals
    def _reset_envs(self, env_ids: torch.Tensor) -> None:
        self._timestep_buf.index_fill_(0, env_ids, 0)
        self._time_buf.index_fill_(0, env_ids, 0.0)
        self._done_buf.index_fill_(0, env_ids, int(DoneFlags.NULL))

    @abc.abstractmethod
    def _apply_action(self, action: torch.Tensor) -> None: ...

    def _step_physics(self) -> None:
        """The engine's control step, then the env clock."""
        self._engine.step()
        self._update_time()

    def _update_time(self) -> None:
        self._timestep_buf += 1
        self._time_buf[:] = self._timestep_buf.float() * self._engine.get_timestep()

    def _update_misc(self) -> None:
        pass

    @abc.abstractmethod
    def _compute_obs(self, env_ids: torch.Tensor | None = None) -> torch.Tensor: ...

    def _update_info(self, env_ids: torch.Tensor | None = None) -> None:
        pass

    def _update_reward(self) -> None:
        self._reward_buf[:] = 1.0

    def _update_done(self) -> None:
        timeout = self._time_buf >= self._episode_length
        self._done_buf[:] = torch.where(timeout, int(DoneFlags.TIME), int(DoneFlags.NULL))
