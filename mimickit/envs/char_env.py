"""CharEnv: one simulated character per env, PD-driven, rewarded 1 per step (the reference's `char`)."""

from __future__ import annotations

import numpy as np
import torch

from mimickit.anim.kin_char_model import JointType, KinCharModel
from mimickit.anim.mjcf_char_model import load_char_model
from mimickit.engines.engine import ControlMode, ObjType
from mimickit.envs.base_env import BoxSpace
from mimickit.envs.char_obs import compute_char_obs
from mimickit.envs.env_config import CharEnvConfig
from mimickit.envs.sim_env import SimEnv
from mimickit.envs.viewable import Viewable
from mimickit.util import torch_util as tu
from mimickit.util.errors import MimicKitError

CHAR_COLOR = (0.35, 0.45, 0.7)


class CharEnv(SimEnv, Viewable):
    config: CharEnvConfig

    # ----------------------------------------------------------- construction
    def _build_envs(self, config: CharEnvConfig, num_envs: int) -> None:
        self._char_file = self.data_paths.resolve(config.char_file)
        self._char_model = load_char_model(self._char_file, self.device)
        self._parse_init_pose(config.init_pose)
        for _ in range(num_envs):
            env_id = self._engine.create_env()
            self._build_env(env_id, config)

    def _build_env(self, env_id: int, config: CharEnvConfig) -> None:
        self._char_id = self._build_character(env_id)

    def _build_character(self, env_id: int) -> int:
        return self._engine.create_obj(
            env_id=env_id,
            obj_type=ObjType.articulated,
            asset_file=str(self._char_file),
            name="character",
            start_pos=self._init_root_pos.cpu().numpy(),
            start_rot=self._init_root_rot.cpu().numpy(),
            color=CHAR_COLOR,
        )

    def _parse_init_pose(self, init_pose: list[float] | None) -> None:
        d = self._char_model.get_dof_size()
        pose = torch.zeros(6 + d, device=self.device)
        if init_pose is not None:
            if len(init_pose) not in (3, 6 + d):
                raise MimicKitError(
                    f"init_pose has {len(init_pose)} values; {self._char_file} needs 3 (root position) or {6 + d}"
                )
            pose[: len(init_pose)] = torch.tensor(init_pose, dtype=torch.float32)
        self._init_root_pos = pose[:3]
        self._init_root_rot = tu.exp_map_to_quat(pose[3:6])
        self._init_dof_pos = pose[6:]

    def _build_action_space(self) -> BoxSpace:
        mode = self._engine.get_control_mode()
        char = self._char_model
        if mode in (ControlMode.pos, ControlMode.pd_explicit):
            low, high = action_bounds_pos(char, self.config.zero_center_action)
        elif mode == ControlMode.vel:
            high = np.full(char.get_dof_size(), 2 * np.pi)
            low = -high
        elif mode == ControlMode.torque:
            high = char.dof_array("torque_limit")
            low = -high
        else:
            high = np.ones(char.get_dof_size())
            low = -high
        return BoxSpace(low.astype(np.float32), high.astype(np.float32))

    def _build_sim_tensors(self, config: CharEnvConfig) -> None:
        names = self._engine.get_obj_body_names(self._char_id)
        if names != self._char_model.get_body_names():
            raise MimicKitError(f"{self._char_file}: engine and kinematic body orders differ")
        self._key_body_ids = torch.tensor(
            [self._char_model.get_body_id(b) for b in config.key_bodies], dtype=torch.long, device=self.device
        )
        self._action_low = torch.tensor(self._action_space.low, device=self.device)
        self._action_high = torch.tensor(self._action_space.high, device=self.device)

    # ---------------------------------------------------------------- public
    @property
    def char_model(self) -> KinCharModel:
        return self._char_model

    def get_char_id(self) -> int:
        return self._char_id

    def get_ref_char_id(self) -> int | None:
        """The object id of the visual reference character (the "ghost") viewers draw, None without one."""
        return None

    def get_char_state(self, env_ids: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """The character's state (root, DoFs, bodies, `joint_rot`) of all envs or `env_ids`: do not write
        into its tensors."""
        return self._char_state(env_ids)

    # ------------------------------------------------------------- internals
    def _reset_envs(self, env_ids: torch.Tensor) -> None:
        super()._reset_envs(env_ids)
        self._reset_char(env_ids)

    def _reset_char(self, env_ids: torch.Tensor) -> None:
        n = len(env_ids)
        e, c = self._engine, self._char_id
        e.set_root_state(env_ids, c, self._init_root_pos.expand(n, -1), self._init_root_rot.expand(n, -1), 0.0, 0.0)
        e.set_dof_pos(env_ids, c, self._init_dof_pos.expand(n, -1))
        e.set_dof_vel(env_ids, c, 0.0)

    def _apply_action(self, action: torch.Tensor) -> None:
        cmd = torch.clamp(action, self._action_low, self._action_high)
        self._engine.set_cmd(self._char_id, cmd)

    def _char_state(self, env_ids: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """The character's live state from the engine (plus `joint_rot`, the DoFs as local joint
        rotations), optionally for a subset of envs. Callers get their own dict and must not write into
        its tensors (an env may answer from what it has read or set already: DeepMimicEnv does)."""
        return self._read_char_state(env_ids)

    def _read_char_state(self, env_ids: torch.Tensor | None) -> dict[str, torch.Tensor]:
        e, c = self._engine, self._char_id
        state = {
            "root_pos": e.get_root_pos(c),
            "root_rot": e.get_root_rot(c),
            "root_vel": e.get_root_vel(c),
            "root_ang_vel": e.get_root_ang_vel(c),
            "dof_pos": e.get_dof_pos(c),
            "dof_vel": e.get_dof_vel(c),
            "body_pos": e.get_body_pos(c),
            "body_rot": e.get_body_rot(c),
            "joint_rot": e.get_joint_rot(c),
        }
        if env_ids is not None:
            state = {k: v.index_select(0, env_ids) for k, v in state.items()}
        return state

    def _compute_obs(self, env_ids: torch.Tensor | None = None) -> torch.Tensor:
        s = self._char_state(env_ids)
        return compute_char_obs(
            s["root_pos"],
            s["root_rot"],
            s["root_vel"],
            s["root_ang_vel"],
            s["joint_rot"],
            s["dof_vel"],
            s["body_pos"].index_select(1, self._key_body_ids),
            self.config.global_obs,
            self.config.root_height_obs,
        )


def action_bounds_pos(char: KinCharModel, zero_center: bool) -> tuple[np.ndarray, np.ndarray]:
    """PD-target bounds: spherical ±1.2·max|limit|; hinge mid ± 1.4·half-range. The reference's, so a
    normalised action means the same PD target in both (and its checkpoints act the same here)."""
    lows, highs = [], []
    for joint in char.joints[1:]:
        if joint.type == JointType.SPHERICAL:
            b = 1.2 * max(np.abs(joint.low).max(), np.abs(joint.high).max())
            lows.append(np.full(3, -b))
            highs.append(np.full(3, b))
        elif joint.type == JointType.HINGE:
            lo, hi = float(joint.low[0]), float(joint.high[0])
            mid = 0.0 if zero_center else 0.5 * (lo + hi)
            half = 1.4 * max(abs(hi - mid), abs(lo - mid))
            lows.append(np.array([mid - half]))
            highs.append(np.array([mid + half]))
    return np.concatenate(lows), np.concatenate(highs)
