"""CharDofTestEnv: sweep one DoF at a time on a fixed-root character to check joint axes and limits.

Every 4 s the active DoF advances (index = floor(t / 4) + env_id, mod D); its command follows
|sin(2π·frac)| toward the action bound on the side of the sine's sign; all other DoFs are held at 0.
The episode lasts 4·D seconds, as in the reference, so every DoF gets its turn.
"""

from __future__ import annotations

import math

import torch

from mimickit.engines.engine import ObjType
from mimickit.envs.char_env import CharEnv
from mimickit.envs.env_config import CharDofTestEnvConfig

PERIOD_S = 4.0


class CharDofTestEnv(CharEnv):
    config: CharDofTestEnvConfig

    def _build_envs(self, config: CharDofTestEnvConfig, num_envs: int) -> None:
        super()._build_envs(config, num_envs)
        self._episode_length = PERIOD_S * self._char_model.get_dof_size()

    def _build_character(self, env_id: int) -> int:
        return self._engine.create_obj(
            env_id=env_id,
            obj_type=ObjType.articulated,
            asset_file=str(self._char_file),
            name="character",
            enable_self_collisions=False,
            fix_root=True,
            start_pos=self._init_root_pos.cpu().numpy(),
            start_rot=self._init_root_rot.cpu().numpy(),
        )

    def _apply_action(self, action: torch.Tensor) -> None:
        d = self._char_model.get_dof_size()
        t = self._time_buf
        env_ids = torch.arange(self.num_envs, device=self.device)
        active = (torch.floor(t / PERIOD_S).long() + env_ids) % d
        s = torch.sin(2.0 * math.pi * (t / PERIOD_S - torch.floor(t / PERIOD_S)))
        bound = torch.where(s < 0, self._action_low[active], self._action_high[active])
        cmd = torch.zeros(self.num_envs, d, device=self.device)
        cmd[env_ids, active] = s.abs() * bound
        self._engine.set_cmd(self._char_id, cmd)
