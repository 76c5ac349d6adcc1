"""AMPTaskEnv: an AMP env with a task on top, the common part of the location and steering envs (as the
reference's task envs).

The task envs keep AMP's character, resets and discriminator observation unchanged and add: a task
observation appended to the character observation, a task reward in `info["reward_terms"]["task"]`
(the agent weighs it against the disc reward with `task_reward_weight`), targets re-sampled at reset
and at a random time U[tar_change_time_min, max] after the previous one, and one visual marker per
env showing the target (only with visualize). The root position is saved before physics so the task
rewards can use the root velocity over the whole control step, as the reference does.
As the reference's, they derive from SMPEnv: an SMP agent may give them a GSI init-state buffer
(`init_gsi_buffer`), which only changes where resets start; without one they are AMP envs.
"""

from __future__ import annotations

import abc

import torch

from mimickit.engines.engine import ObjType
from mimickit.envs.env_config import TaskLocationEnvConfig, TaskSteeringEnvConfig
from mimickit.envs.smp_env import SMPEnv
from mimickit.envs.viewable import ShowsTaskTarget
from mimickit.util import torch_util as tu

MARKER_COLOR = (0.8, 0.3, 0.1)


class AMPTaskEnv(SMPEnv, ShowsTaskTarget, abc.ABC):
    config: TaskLocationEnvConfig | TaskSteeringEnvConfig  # type: ignore[assignment]
    marker_file = ""  # MJCF of the target marker (data/... path, looked up like every asset)

    # ----------------------------------------------------------- construction
    def _build_env(self, env_id: int, config: TaskLocationEnvConfig | TaskSteeringEnvConfig) -> None:  # type: ignore[override]
        super()._build_env(env_id, config)
        if self._visualize:  # markers only matter to a viewer; training runs without them
            self._marker_id = self._engine.create_obj(
                env_id=env_id,
                obj_type=ObjType.rigid,
                asset_file=str(self.data_paths.resolve(self.marker_file)),
                name="marker",
                is_visual=True,
                color=MARKER_COLOR,
            )

    def _build_sim_tensors(self, config: TaskLocationEnvConfig | TaskSteeringEnvConfig) -> None:  # type: ignore[override]
        super()._build_sim_tensors(config)
        n, dev = self.num_envs, self.device
        self._prev_root_pos = torch.zeros(n, 3, device=dev)
        self._tar_change_time = torch.zeros(n, device=dev)
        self._build_task_buffers()

    @abc.abstractmethod
    def _build_task_buffers(self) -> None:
        """Allocate the target buffers [N, ...] (called before the first reset)."""

    # ---------------------------------------------------------------- public
    def has_markers(self) -> bool:
        return hasattr(self, "_marker_id")

    def get_marker_id(self) -> int:
        """The engine object of the target marker (built only with visualize), as a viewer looks it up."""
        if not self.has_markers():
            raise ValueError("this env has no markers: they are built only with visualize")
        return self._marker_id

    def get_target_change_time(self) -> torch.Tensor:
        """Each env's env time [N] (seconds) at which its target is next resampled."""
        return self._tar_change_time

    # -------------------------------------------------------------- targets
    def _resample_targets(self, env_ids: torch.Tensor) -> None:
        """New targets for env_ids and the env time of their next change."""
        if len(env_ids) == 0:
            return
        lo, hi = self.config.tar_change_time_min, self.config.tar_change_time_max
        wait = lo + (hi - lo) * torch.rand(len(env_ids), device=self.device)
        self._tar_change_time[env_ids] = self.get_env_time(env_ids) + wait
        self._sample_targets(env_ids)
        if self.has_markers():
            self._place_markers(env_ids)

    @abc.abstractmethod
    def _sample_targets(self, env_ids: torch.Tensor) -> None:
        """Draw new targets for env_ids."""

    @abc.abstractmethod
    def _place_markers(self, env_ids: torch.Tensor) -> None:
        """Pose the markers of env_ids to show their targets."""

    @abc.abstractmethod
    def _compute_task_obs(self, env_ids: torch.Tensor) -> torch.Tensor:
        """Task observation [n, task_obs_dim] of env_ids."""

    def _root_pos(self, env_ids: torch.Tensor | None = None) -> torch.Tensor:
        pos = self._engine.get_root_pos(self._char_id)
        return pos if env_ids is None else pos[env_ids]

    def _root_rot(self, env_ids: torch.Tensor | None = None) -> torch.Tensor:
        rot = self._engine.get_root_rot(self._char_id)
        return rot if env_ids is None else rot[env_ids]

    def _root_speed(self, env_ids: torch.Tensor | None = None) -> torch.Tensor:
        """Mean root velocity [n, 3] over the last control step (0 right after a reset)."""
        prev = self._prev_root_pos if env_ids is None else self._prev_root_pos[env_ids]
        return (self._root_pos(env_ids) - prev) / self._engine.get_timestep()

    # ---------------------------------------------------------------- per step
    def _apply_action(self, action: torch.Tensor) -> None:
        self._prev_root_pos[:] = self._root_pos()
        super()._apply_action(action)

    def _reset_envs(self, env_ids: torch.Tensor) -> None:
        super()._reset_envs(env_ids)
        self._prev_root_pos[env_ids] = self._root_pos(env_ids)
        self._resample_targets(env_ids)

    def _update_misc(self) -> None:
        super()._update_misc()
        due = torch.nonzero(self.get_env_time() >= self._tar_change_time).flatten()
        self._resample_targets(due)

    def _compute_obs(self, env_ids: torch.Tensor | None = None) -> torch.Tensor:
        ids = torch.arange(self.num_envs, device=self.device) if env_ids is None else env_ids
        return torch.cat([super()._compute_obs(env_ids), self._compute_task_obs(ids)], dim=-1)


def heading_dir(root_rot: torch.Tensor) -> torch.Tensor:
    """Unit xy direction [n, 2] the character faces (heading of root_rot [n, 4], xyzw)."""
    h = tu.calc_heading(root_rot)
    return torch.stack([torch.cos(h), torch.sin(h)], dim=-1)


def to_heading_frame(root_rot: torch.Tensor, vec_xy: torch.Tensor) -> torch.Tensor:
    """xy vectors [n, 2] expressed in the character's heading frame (x forward, y left)."""
    d = heading_dir(root_rot)
    x = d[:, 0] * vec_xy[:, 0] + d[:, 1] * vec_xy[:, 1]
    y = -d[:, 1] * vec_xy[:, 0] + d[:, 0] * vec_xy[:, 1]
    return torch.stack([x, y], dim=-1)
