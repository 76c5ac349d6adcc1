"""TaskLocationEnv (`task_location`): AMP style while walking to a target on the ground, as the reference's.

Target: the root's xy plus d·(cos φ, sin φ), d ~ U[tar_dist_min, tar_dist_max], φ ~ U[0, 2π), z 0.
Task obs (2): the target relative to the root in the heading frame. Task reward: position, velocity
towards the target and facing terms (`location_reward`). The env also records, for every episode
that ends, whether the character had reached its current target (squared xy distance below
`dist_threshold` since the target was set); `record_diagnostics()` reports the share.
"""

from __future__ import annotations

import math

import torch

from mimickit.envs.base_env import DoneFlags
from mimickit.envs.env_config import TaskLocationEnvConfig
from mimickit.envs.task_env import AMPTaskEnv, heading_dir, to_heading_frame


class TaskLocationEnv(AMPTaskEnv):
    config: TaskLocationEnvConfig  # type: ignore[assignment]
    marker_file = "data/assets/objects/location_marker.xml"

    def _build_task_buffers(self) -> None:
        n, dev = self.num_envs, self.device
        self._tar_pos = torch.zeros(n, 3, device=dev)
        self._tar_reached = torch.zeros(n, dtype=torch.bool, device=dev)
        self._episodes_done = 0
        self._episodes_reached = 0

    # ---------------------------------------------------------------- public
    def get_tar_pos(self) -> torch.Tensor:
        """Target positions [N, 3] (z = 0)."""
        return self._tar_pos

    def task_target(self, env_id: int = 0) -> dict[str, float | bool | str]:
        """The target's xy, its distance from the root (m) and whether this target was reached."""
        tar, root = self._tar_pos[env_id], self._root_pos()[env_id]
        return {
            "kind": "location",
            "x": round(float(tar[0]), 3),
            "y": round(float(tar[1]), 3),
            "distance_m": round(float((tar[:2] - root[:2]).norm()), 3),
            "reached": bool(self._tar_reached[env_id]),
        }

    def record_diagnostics(self) -> dict[str, float]:
        """Episodes that ended since the previous call and the share that reached their target
        (0 when none ended: read it together with the count)."""
        done, reached = self._episodes_done, self._episodes_reached
        self._episodes_done = self._episodes_reached = 0
        return {"tar_episodes": float(done), "tar_reached_frac": reached / done if done else 0.0}

    # -------------------------------------------------------------- targets
    def _sample_targets(self, env_ids: torch.Tensor) -> None:
        n, cfg = len(env_ids), self.config
        dist = cfg.tar_dist_min + (cfg.tar_dist_max - cfg.tar_dist_min) * torch.rand(n, device=self.device)
        angle = 2 * math.pi * torch.rand(n, device=self.device)
        offset = dist.unsqueeze(-1) * torch.stack([torch.cos(angle), torch.sin(angle)], dim=-1)
        self._tar_pos[env_ids, :2] = self._root_pos(env_ids)[:, :2] + offset
        self._tar_pos[env_ids, 2] = 0.0
        self._tar_reached[env_ids] = False

    def _place_markers(self, env_ids: torch.Tensor) -> None:
        e, m = self._engine, self._marker_id
        identity = torch.tensor([0.0, 0.0, 0.0, 1.0], device=self.device).expand(len(env_ids), 4)
        e.set_root_state(env_ids, m, self._tar_pos[env_ids], identity, 0.0, 0.0)

    # ---------------------------------------------------------------- per step
    def _compute_task_obs(self, env_ids: torch.Tensor) -> torch.Tensor:
        delta = self._tar_pos[env_ids, :2] - self._root_pos(env_ids)[:, :2]
        return to_heading_frame(self._root_rot(env_ids), delta)

    def _compute_task_reward(self, env_ids: torch.Tensor | None = None) -> torch.Tensor:
        ids = torch.arange(self.num_envs, device=self.device) if env_ids is None else env_ids
        root_pos, tar_pos = self._root_pos(ids), self._tar_pos[ids]
        return location_reward(root_pos, self._root_speed(ids), heading_dir(self._root_rot(ids)), tar_pos, self.config)

    def _update_misc(self) -> None:
        super()._update_misc()  # may set new targets: they start unreached
        pos_err = ((self._tar_pos[:, :2] - self._root_pos()[:, :2]) ** 2).sum(-1)
        self._tar_reached |= pos_err < self.config.dist_threshold

    def _update_done(self) -> None:
        super()._update_done()
        ended = self._done_buf != DoneFlags.NULL
        self._episodes_done += int(ended.sum())
        self._episodes_reached += int((ended & self._tar_reached).sum())


def location_reward(
    root_pos: torch.Tensor,
    root_vel: torch.Tensor,
    facing: torch.Tensor,
    tar_pos: torch.Tensor,
    cfg: TaskLocationEnvConfig,
) -> torch.Tensor:
    """r = w_pos·exp(−pos_err_scale·|Δxy|²) + w_vel·r_vel + w_face·max(u·facing, 0) [n], the reference's.

    root_pos, root_vel [n, 3] (velocity over the last control step), facing [n, 2] unit heading, tar_pos
    [n, 3]; u is the unit xy direction to the target. r_vel = exp(−vel_err_scale·max(tar_speed − v·u, 0)²),
    0 when moving away; within dist_threshold (squared distance) velocity and facing score 1 so the
    character may stand at the target.
    """
    delta = tar_pos[:, :2] - root_pos[:, :2]
    pos_err = (delta**2).sum(-1)
    r_pos = torch.exp(-cfg.pos_err_scale * pos_err)
    u = delta / delta.norm(dim=-1, keepdim=True).clamp_min(1e-5)
    speed_along = (u * root_vel[:, :2]).sum(-1)
    vel_err = (cfg.tar_speed - speed_along).clamp_min(0.0)
    r_vel = torch.where(speed_along > 0, torch.exp(-cfg.vel_err_scale * vel_err**2), torch.zeros_like(vel_err))
    r_face = (u * facing).sum(-1).clamp_min(0.0)
    near = pos_err < cfg.dist_threshold
    r_vel = torch.where(near, torch.ones_like(r_vel), r_vel)
    r_face = torch.where(near, torch.ones_like(r_face), r_face)
    return cfg.pos_reward_w * r_pos + cfg.vel_reward_w * r_vel + cfg.face_reward_w * r_face
