"""AMPEnv: DeepMimic's character and reference-state init, scored by a discriminator, as the reference's `amp`.

The env keeps a history of the last `num_disc_obs_steps` character states and turns it into the
discriminator observation `info["disc_obs"]` [N, disc_obs_dim] after every step and reset;
`fetch_disc_obs_demo(n)` computes the same features from the motion clips. The env's own reward is
the task reward (none for plain AMP: 0, as the reference); the agent builds the training reward from
the discriminator. So that viewers and metrics see the style reward per step, an agent may attach
its discriminator with `set_disc_reward_fn`: `info["reward_terms"]` then holds `task` and `disc`
(both unweighted, [N]) and `reward_weights` their weights.

Differences from DeepMimicEnv: no imitation reward or tracking errors, no SUCC at the end of a clip
(motion_len_term False), and the reference is re-evaluated every step only when the visual
reference character needs it (otherwise only at reset, as the reference).
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from mimickit.envs.base_env import BoxSpace, DoneFlags
from mimickit.envs.char_obs import compute_tar_obs
from mimickit.envs.deepmimic_env import DeepMimicEnv
from mimickit.envs.env_config import AMPEnvConfig
from mimickit.util import torch_util as tu

DiscRewardFn = Callable[[torch.Tensor], torch.Tensor]
"""disc obs [n, disc_obs_dim] → unweighted discriminator reward [n]."""

DISC_HIST_KEYS = ("root_pos", "root_rot", "root_vel", "root_ang_vel", "joint_rot", "dof_vel", "body_pos")


class AMPEnv(DeepMimicEnv):
    config: AMPEnvConfig  # type: ignore[assignment]

    # ----------------------------------------------------------- construction
    def _build_sim_tensors(self, config: AMPEnvConfig) -> None:
        super()._build_sim_tensors(config)
        self._num_disc_obs_steps = config.num_disc_obs_steps
        # Bodies whose positions the disc obs holds (AMP: the key bodies; ADD: all of them).
        self._disc_body_ids = self._key_body_ids
        self._disc_reward_fn: DiscRewardFn | None = None
        self._reward_weights = {"task": 1.0}

    def _build_data_buffers(self) -> None:
        super()._build_data_buffers()
        # Any valid history will do until the first reset fills it from the clip.
        self._disc_hist = self._motion_history(self._motion_ids, self.get_motion_time())
        self._disc_obs_buf = self._disc_obs_from_hist(self._disc_hist)
        self._disc_obs_space = BoxSpace.unbounded(self._disc_obs_buf.shape[-1])
        self._info["disc_obs"] = self._disc_obs_buf

    # ---------------------------------------------------------------- public
    def get_disc_obs_space(self) -> BoxSpace:
        return self._disc_obs_space

    def get_num_disc_obs_steps(self) -> int:
        return self._num_disc_obs_steps

    def get_disc_history(self) -> dict[str, torch.Tensor]:
        """The character's last `num_disc_obs_steps` states the disc obs are built from, oldest first
        ([N, steps, ...] per field, world frame): what the discriminator sees, before it is made relative."""
        return self._disc_hist

    def fetch_disc_obs_demo(self, num_samples: int) -> torch.Tensor:
        """Disc obs [num_samples, disc_obs_dim] of the clips: motions drawn by weight, end times drawn
        like a reset (uniform over the clip with `rand_reset`, else 0), history reaching back before them."""
        lib = self._motion_lib
        ids = lib.sample_motions(num_samples).to(self.device)
        times = lib.sample_time(ids) if self.config.rand_reset else torch.zeros(num_samples, device=self.device)
        return self._disc_obs_from_hist(self._motion_history(ids, times))

    def set_disc_reward_fn(self, fn: DiscRewardFn | None, task_weight: float = 1.0, disc_weight: float = 1.0) -> None:
        """Score every step's disc obs with `fn` into `info["reward_terms"]["disc"]` (None: stop)."""
        self._disc_reward_fn = fn
        self._reward_weights = {"task": task_weight} if fn is None else {"task": task_weight, "disc": disc_weight}
        self._info.pop("reward_terms", None)  # rebuilt with the new set of terms at the next update

    # ------------------------------------------------------------- history
    def _motion_history(self, motion_ids: torch.Tensor, end_times: torch.Tensor) -> dict[str, torch.Tensor]:
        """Reference states at end_time − (S−1)·dt … end_time (oldest first) for ids / end_times [n]:
        each value [n, S, ...] with S = num_disc_obs_steps."""
        n, s = len(motion_ids), self._num_disc_obs_steps
        offsets = self._engine.get_timestep() * torch.arange(s - 1, -1, -1, device=self.device, dtype=torch.float32)
        times = (end_times.unsqueeze(-1) - offsets).flatten()
        f = self._motion_lib.calc_motion_frame(motion_ids.repeat_interleave(s), times)
        body_pos, _ = self._char_model.forward_kinematics(f.root_pos, f.root_rot, f.joint_rot)
        hist = {
            "root_pos": f.root_pos, "root_rot": f.root_rot, "root_vel": f.root_vel, "root_ang_vel": f.root_ang_vel,
            "joint_rot": f.joint_rot, "dof_vel": f.dof_vel, "body_pos": body_pos[:, self._disc_body_ids],
        }  # fmt: skip
        return {k: v.reshape(n, s, *v.shape[1:]) for k, v in hist.items()}

    def _push_disc_hist(self) -> None:
        """Shift every history one step back and append the character's live state as the newest."""
        state = self._char_state()
        state["body_pos"] = state["body_pos"][:, self._disc_body_ids]
        for k in DISC_HIST_KEYS:
            buf = self._disc_hist[k]
            buf[:, :-1] = buf[:, 1:].clone()
            buf[:, -1] = state[k]

    def _reset_disc_hist(self, env_ids: torch.Tensor) -> None:
        """The history of reset envs is the clip leading up to their reset time (not the init pose)."""
        hist = self._motion_history(self._motion_ids[env_ids], self.get_motion_time(env_ids))
        for k in DISC_HIST_KEYS:
            self._disc_hist[k][env_ids] = hist[k]

    def _disc_obs_from_hist(self, hist: dict[str, torch.Tensor]) -> torch.Tensor:
        newest = {k: v[:, -1] for k, v in hist.items()}
        if self._track_root:  # global root tracking: positions stay in the world frame
            ref_pos = torch.zeros_like(newest["root_pos"])
            ref_rot = tu.quat_identity(tuple(ref_pos.shape[:-1]), device=self.device)
        else:
            ref_pos, ref_rot = newest["root_pos"], newest["root_rot"]
        return compute_disc_obs(
            ref_pos, ref_rot, hist, self.config.global_obs, self.config.root_height_obs, self.config.disc_dof_vel_obs
        )

    # ---------------------------------------------------------------- per step
    def _reset_envs(self, env_ids: torch.Tensor) -> None:
        super()._reset_envs(env_ids)
        self._reset_disc_hist(env_ids)

    @property
    def tracks_pose(self) -> bool:
        return False  # the discriminator rewards the style of the clips, not the reference's pose

    def _ref_each_step(self) -> bool:
        # AMP neither tracks nor rewards the reference: only the visual twin needs it every step.
        return self._enable_ref_char

    def _update_misc(self) -> None:
        super()._update_misc()
        self._push_disc_hist()

    def _update_info(self, env_ids: torch.Tensor | None = None) -> None:
        """Disc obs of the given envs (all when None), then the per-step reward terms."""
        disc_obs = self._update_disc_obs(env_ids)
        if env_ids is None and self.config.pose_termination:
            self._last_sim = self._sim_state()
        self._store_reward_terms(disc_obs, env_ids)

    def _update_disc_obs(self, env_ids: torch.Tensor | None) -> torch.Tensor:
        """Disc obs [n, disc_obs_dim] of the given envs' histories, also written into the info buffer."""
        hist = self._disc_hist if env_ids is None else {k: v[env_ids] for k, v in self._disc_hist.items()}
        disc_obs = self._disc_obs_from_hist(hist)
        if env_ids is None:
            self._disc_obs_buf[:] = disc_obs
        else:
            self._disc_obs_buf[env_ids] = disc_obs
        return disc_obs

    def _store_reward_terms(self, disc_input: torch.Tensor, env_ids: torch.Tensor | None) -> None:
        """`task`, and `disc` = the attached discriminator's reward of disc_input [n, disc_obs_dim]."""
        terms = {"task": self._compute_task_reward(env_ids)}
        if self._disc_reward_fn is not None:
            terms["disc"] = self._disc_reward_fn(disc_input)
        self._store_info("reward_terms", terms, env_ids)

    def _compute_task_reward(self, env_ids: torch.Tensor | None = None) -> torch.Tensor:
        """Task reward [n] of the given envs; plain AMP has no task (task envs override this)."""
        n = self.num_envs if env_ids is None else len(env_ids)
        return torch.zeros(n, device=self.device)

    def _update_reward(self) -> None:
        self._reward_buf[:] = self._info["reward_terms"]["task"]

    def _update_done(self) -> None:
        super(DeepMimicEnv, self)._update_done()  # TIME only: the end of a clip is no success for AMP
        if self.config.enable_early_termination:
            self._done_buf[self._fallen() | self._pose_failed()] = DoneFlags.FAIL


def compute_disc_obs(
    ref_root_pos: torch.Tensor,
    ref_root_rot: torch.Tensor,
    hist: dict[str, torch.Tensor],
    global_obs: bool,
    root_height_obs: bool,
    dof_vel_obs: bool,
) -> torch.Tensor:
    """Discriminator observation of a state history, laid out as the reference's.

    hist holds S steps, oldest first: root_pos / root_vel / root_ang_vel [N,S,3], root_rot [N,S,4],
    joint_rot [N,S,J-1,4], dof_vel [N,S,D], body_pos [N,S,K,3] (AMP: the K key bodies); the positions
    are taken relative to ref_root_pos [N,3] (heading of ref_root_rot [N,4] when local). Per step: root
    position (z absolute with root_height_obs), root rotation, joint rotations, body positions relative
    to that step's root, root velocity, root angular velocity, [dof velocities]
    → [N, S·(3|2 + 6 + 6(J-1) + 3K + 6 [+ D])].
    """
    n, s = hist["root_pos"].shape[:2]
    pos_obs = compute_tar_obs(
        ref_root_pos, ref_root_rot, hist["root_pos"], hist["root_rot"], hist["joint_rot"], hist["body_pos"],
        global_obs, root_height_obs,
    ).view(n, s, -1)  # fmt: skip
    vel, ang_vel = hist["root_vel"], hist["root_ang_vel"]
    if not global_obs:
        heading_inv = tu.calc_heading_quat_inv(ref_root_rot).unsqueeze(-2)  # [N,1,4]
        vel, ang_vel = tu.quat_rotate(heading_inv, vel), tu.quat_rotate(heading_inv, ang_vel)
    parts = [pos_obs, vel, ang_vel]
    if dof_vel_obs:
        parts.append(hist["dof_vel"])
    return torch.cat(parts, dim=-1).flatten(-2)
