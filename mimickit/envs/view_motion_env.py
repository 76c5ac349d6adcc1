"""ViewMotionEnv: plays clips through the engine, kinematically (the reference's `view_motion`).

Every step overwrites the character's state with the clip at the env's time (clip = env_id mod #clips);
physics runs at the control rate with motors off, so the engine's body poses are the clip's FK.
"""

from __future__ import annotations

import torch

from mimickit.anim.motion import LoopMode
from mimickit.anim.motion_lib import MotionLib
from mimickit.engines.engine import EngineConfig, ObjType
from mimickit.envs.base_env import DoneFlags
from mimickit.envs.char_env import CharEnv
from mimickit.envs.env_config import ViewMotionEnvConfig


class ViewMotionEnv(CharEnv):
    config: ViewMotionEnvConfig

    def __init__(self, env_config: ViewMotionEnvConfig, engine_config: EngineConfig, *args, **kwargs) -> None:
        engine_config = engine_config.model_copy(update={"sim_freq": engine_config.control_freq})
        super().__init__(env_config, engine_config, *args, **kwargs)

    def _build_envs(self, config: ViewMotionEnvConfig, num_envs: int) -> None:
        super()._build_envs(config, num_envs)
        self._motion_lib = MotionLib(config.motion_file, self._char_model, self.device, data_paths=self.data_paths)
        self._motion_ids = torch.arange(num_envs, device=self.device) % self._motion_lib.num_motions()

    def _build_character(self, env_id: int) -> int:
        return self._engine.create_obj(
            env_id=env_id,
            obj_type=ObjType.articulated,
            asset_file=str(self._char_file),
            name="character",
            enable_self_collisions=False,
            disable_motors=True,
            start_pos=self._init_root_pos.cpu().numpy(),
            start_rot=self._init_root_rot.cpu().numpy(),
        )

    @property
    def motion_lib(self) -> MotionLib:
        return self._motion_lib

    def _reset_char(self, env_ids: torch.Tensor) -> None:
        self._sync_motion(env_ids, torch.zeros(len(env_ids), device=self.device))

    def _apply_action(self, action: torch.Tensor) -> None:
        pass

    def _update_misc(self) -> None:
        ids = torch.arange(self.num_envs, device=self.device)
        self._sync_motion(ids, self._time_buf)

    def _sync_motion(self, env_ids: torch.Tensor, times: torch.Tensor) -> None:
        lib, e, c = self._motion_lib, self._engine, self._char_id
        f = lib.calc_motion_frame(self._motion_ids[env_ids], times)
        e.set_root_state(env_ids, c, f.root_pos, f.root_rot, f.root_vel, f.root_ang_vel)
        e.set_joint_rot(env_ids, c, f.joint_rot)
        e.set_dof_vel(env_ids, c, f.dof_vel)

    def _update_done(self) -> None:
        length = self._motion_lib.get_motion_length(self._motion_ids)
        wrap = self._motion_lib.get_motion_loop_mode(self._motion_ids) == LoopMode.WRAP
        limit = torch.where(wrap, 5.0 * length, length)
        self._done_buf[:] = torch.where(self._time_buf >= limit, int(DoneFlags.TIME), int(DoneFlags.NULL))
