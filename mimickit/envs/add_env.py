"""ADDEnv: adversarial differential discriminators (the reference's `add`): DeepMimic's tracking task, scored by a
discriminator of the *difference* between the reference and the character.

Every step and reset the env provides, for each env, `info["disc_obs"]` [N, disc_obs_dim], the ADD
features of the character's state history, and `info["disc_obs_demo"]` [N, disc_obs_dim], the same
features of the reference clip at the env's current motion time (history ending now). The agent's
discriminator sees `disc_obs_demo − disc_obs`; an attached disc reward fn (`set_disc_reward_fn`)
therefore receives that difference, and `info["reward_terms"]` holds `task` (0: no task) and `disc`.

Per step, ADD features are: root position (absolute with global obs; xy zeroed, height kept when
local), root rotation, joint rotations, the positions of *all* bodies relative to the root, root
velocity, root angular velocity, DoF velocities — local quantities in the step's own heading frame.
Humanoid: 3 + 6 + 14·6 + 15·3 + 3 + 3 + 28 = 172 per step.

Unlike AMPEnv, the reference is re-evaluated every step (as DeepMimic), the end of a clamped clip is a
success, pose termination applies as configured, and the tracking errors are reported
(`info["tracking"]`, TEST-mode means in `record_diagnostics` with `log_tracking_error`).
"""

from __future__ import annotations

import torch

from mimickit.envs.amp_env import AMPEnv, compute_disc_obs
from mimickit.envs.deepmimic_env import DeepMimicEnv
from mimickit.envs.env_config import ADDEnvConfig
from mimickit.util import torch_util as tu


class ADDEnv(AMPEnv):
    config: ADDEnvConfig  # type: ignore[assignment]

    # ----------------------------------------------------------- construction
    def _build_sim_tensors(self, config: ADDEnvConfig) -> None:
        super()._build_sim_tensors(config)
        self._disc_body_ids = torch.arange(self._char_model.get_num_joints(), device=self.device)

    def _build_data_buffers(self) -> None:
        super()._build_data_buffers()
        self._disc_obs_demo_buf = self._demo_disc_obs(torch.arange(self.num_envs, device=self.device))
        self._info["disc_obs_demo"] = self._disc_obs_demo_buf

    # ---------------------------------------------------------------- public
    def get_disc_obs_demo(self) -> torch.Tensor:
        """[N, disc_obs_dim]: ADD features of each env's reference at its current motion time (the
        buffer behind `info["disc_obs_demo"]`, updated in place)."""
        return self._disc_obs_demo_buf

    # ---------------------------------------------------------------- features
    def _disc_obs_from_hist(self, hist: dict[str, torch.Tensor]) -> torch.Tensor:
        return compute_add_disc_obs(hist, self.config.global_obs, self.config.disc_dof_vel_obs)

    def _demo_disc_obs(self, env_ids: torch.Tensor) -> torch.Tensor:
        """ADD features [n, disc_obs_dim] of the reference of the given envs, history ending now."""
        if self._num_disc_obs_steps == 1:  # the reference buffers already hold the clip at this time
            hist = {k: self._ref[k][env_ids].unsqueeze(1) for k in self._disc_hist}
        else:
            hist = self._motion_history(self._motion_ids[env_ids], self.get_motion_time(env_ids))
        return self._disc_obs_from_hist(hist)

    # ---------------------------------------------------------------- per step
    @property
    def tracks_pose(self) -> bool:
        return True  # its discriminator judges the difference to the reference's pose

    def _ref_each_step(self) -> bool:
        return True  # the reference every step: tracking, pose termination, demo disc obs

    def _update_info(self, env_ids: torch.Tensor | None = None) -> None:
        """Tracking errors (DeepMimic's), agent and demo disc obs of the given envs (all when None), reward
        terms."""
        if env_ids is None:
            self._last_sim = self._sim_state()  # the state pose termination reads
            self._update_tracking(None, self._last_sim, self._ref_state())
        else:
            self._update_tracking(env_ids)
        ids = self._all_env_ids if env_ids is None else env_ids
        disc_obs = self._update_disc_obs(env_ids)
        demo = self._demo_disc_obs(ids)
        self._disc_obs_demo_buf[ids] = demo
        self._store_reward_terms(demo - disc_obs, env_ids)

    def _update_done(self) -> None:
        DeepMimicEnv._update_done(self)  # a clamped clip's end is a success, as in DeepMimic


def compute_add_disc_obs(hist: dict[str, torch.Tensor], global_obs: bool, dof_vel_obs: bool) -> torch.Tensor:
    """ADD disc obs of a state history, as the reference's: every step in its own frame.

    hist holds S steps, oldest first: root_pos / root_vel / root_ang_vel [N,S,3], root_rot [N,S,4],
    joint_rot [N,S,J-1,4], dof_vel [N,S,D], body_pos [N,S,B,3] (all B bodies) →
    [N, S·(3 + 6 + 6(J-1) + 3B + 6 [+ D])]. AMP's features with each step as its own sample and its own
    reference: the world origin with global obs (absolute root position), else the step's root (xy 0,
    absolute height, heading frame); the root height is always kept.
    """
    n, s = hist["root_pos"].shape[:2]
    steps = {k: v.reshape(n * s, 1, *v.shape[2:]) for k, v in hist.items()}
    root_pos, root_rot = steps["root_pos"][:, 0], steps["root_rot"][:, 0]
    if global_obs:
        ref_pos, ref_rot = torch.zeros_like(root_pos), tu.quat_identity((n * s,), device=root_pos.device)
    else:
        ref_pos, ref_rot = root_pos, root_rot
    obs = compute_disc_obs(ref_pos, ref_rot, steps, global_obs, root_height_obs=True, dof_vel_obs=dof_vel_obs)
    return obs.view(n, -1)
