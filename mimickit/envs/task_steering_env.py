"""TaskSteeringEnv (`task_steering`): AMP style while moving in a commanded direction, as the reference's.

Per change: a target direction (angle U[−π, π) with rand_tar_dir, else 0), a facing direction (U[−π, π)
with rand_face_dir, else the target direction) and a speed U[tar_speed_min, tar_speed_max]. Task obs
(5): heading-frame target direction (2), target speed (1), heading-frame facing direction (2).
"""

from __future__ import annotations

import math

import torch

from mimickit.envs.env_config import TaskSteeringEnvConfig
from mimickit.envs.task_env import AMPTaskEnv, heading_dir, to_heading_frame
from mimickit.util import torch_util as tu

MARKER_LEAD = 1.0  # m ahead of the root along the target direction, so the arrow is not hidden in the body
MARKER_HEIGHT = 0.1  # m


class TaskSteeringEnv(AMPTaskEnv):
    config: TaskSteeringEnvConfig  # type: ignore[assignment]
    marker_file = "data/assets/objects/steering_marker.xml"

    def _build_task_buffers(self) -> None:
        n, dev = self.num_envs, self.device
        self._tar_dir = torch.zeros(n, 2, device=dev)
        self._tar_dir[:, 0] = 1.0
        self._face_dir = self._tar_dir.clone()
        self._tar_speed = torch.zeros(n, device=dev)

    # ---------------------------------------------------------------- public
    def get_targets(self) -> dict[str, torch.Tensor]:
        """tar_dir [N, 2], face_dir [N, 2] (unit, world xy) and tar_speed [N] (m/s)."""
        return {"tar_dir": self._tar_dir, "face_dir": self._face_dir, "tar_speed": self._tar_speed}

    def task_target(self, env_id: int = 0) -> dict[str, float | bool | str]:
        """The commanded direction and facing (degrees, world frame, x = 0°) and speed, and the root's
        speed along the commanded direction over the last control step (m/s)."""
        d, f = self._tar_dir[env_id], self._face_dir[env_id]
        along = float((self._root_speed()[env_id, :2] * d).sum())
        return {
            "kind": "steering",
            "heading_deg": round(math.degrees(math.atan2(float(d[1]), float(d[0]))), 1),
            "facing_deg": round(math.degrees(math.atan2(float(f[1]), float(f[0]))), 1),
            "speed_mps": round(float(self._tar_speed[env_id]), 3),
            "speed_along_mps": round(along, 3),
        }

    # -------------------------------------------------------------- targets
    def _sample_targets(self, env_ids: torch.Tensor) -> None:
        n, cfg, dev = len(env_ids), self.config, self.device
        tar_angle = (2 * torch.rand(n, device=dev) - 1) * math.pi if cfg.rand_tar_dir else torch.zeros(n, device=dev)
        face_angle = (2 * torch.rand(n, device=dev) - 1) * math.pi if cfg.rand_face_dir else tar_angle
        self._tar_dir[env_ids] = torch.stack([torch.cos(tar_angle), torch.sin(tar_angle)], dim=-1)
        self._face_dir[env_ids] = torch.stack([torch.cos(face_angle), torch.sin(face_angle)], dim=-1)
        speed_range = cfg.tar_speed_max - cfg.tar_speed_min
        self._tar_speed[env_ids] = cfg.tar_speed_min + speed_range * torch.rand(n, device=dev)

    def _place_markers(self, env_ids: torch.Tensor) -> None:
        """An arrow ahead of the character pointing along the target direction."""
        e, m, d = self._engine, self._marker_id, self._tar_dir[env_ids]
        pos = self._root_pos(env_ids).clone()
        pos[:, :2] += MARKER_LEAD * d
        pos[:, 2] = MARKER_HEIGHT
        z = torch.zeros(len(env_ids), 3, device=self.device)
        z[:, 2] = 1.0
        e.set_root_state(env_ids, m, pos, tu.quat_from_axis_angle(z, torch.atan2(d[:, 1], d[:, 0])), 0.0, 0.0)

    # ---------------------------------------------------------------- per step
    def _update_misc(self) -> None:
        super()._update_misc()
        if self.has_markers():  # the arrow follows the character
            self._place_markers(self._all_env_ids)

    def _compute_task_obs(self, env_ids: torch.Tensor) -> torch.Tensor:
        rot = self._root_rot(env_ids)
        return torch.cat(
            [
                to_heading_frame(rot, self._tar_dir[env_ids]),
                self._tar_speed[env_ids].unsqueeze(-1),
                to_heading_frame(rot, self._face_dir[env_ids]),
            ],
            dim=-1,
        )

    def _compute_task_reward(self, env_ids: torch.Tensor | None = None) -> torch.Tensor:
        ids = torch.arange(self.num_envs, device=self.device) if env_ids is None else env_ids
        return steering_reward(
            self._root_speed(ids), heading_dir(self._root_rot(ids)), self._tar_dir[ids], self._tar_speed[ids],
            self._face_dir[ids], self.config,
        )  # fmt: skip


def steering_reward(
    root_vel: torch.Tensor,
    facing: torch.Tensor,
    tar_dir: torch.Tensor,
    tar_speed: torch.Tensor,
    face_dir: torch.Tensor,
    cfg: TaskSteeringEnvConfig,
) -> torch.Tensor:
    """r = w_tar·exp(−k·|speed·dir − v.xy|²) (0 when moving against dir) + w_face·max(face_dir·facing, 0) [n].

    root_vel [n, 3] over the last control step, facing / tar_dir / face_dir [n, 2] unit, tar_speed [n].
    """
    vel = root_vel[:, :2]
    err = ((tar_speed.unsqueeze(-1) * tar_dir - vel) ** 2).sum(-1)
    r_tar = torch.exp(-cfg.reward_steering_vel_scale * err)
    r_tar = torch.where((tar_dir * vel).sum(-1) < 0, torch.zeros_like(r_tar), r_tar)
    r_face = (face_dir * facing).sum(-1).clamp_min(0.0)
    return cfg.reward_steering_tar_w * r_tar + cfg.reward_steering_face_w * r_face
