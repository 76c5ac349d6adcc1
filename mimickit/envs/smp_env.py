"""SMPEnv (`smp`): the AMP env plus generative state initialisation (GSI), as the reference's `SMPEnv`.

An SMP agent scores the character with a motion prior trained on disc-obs windows; with GSI it also draws
windows from that prior and hands them here (`init_gsi_buffer`, then `add_gsi_samples` to refresh):
unnormalised disc obs [B, S·step] or [B, S, step] (S = num_disc_obs_steps). Each window becomes motion
frames (root position from the first 3 values of a step, root and joint rotations from their tangent-normal
pairs: the reference's `_disc_obs_to_motion_frames`), then init states (FK bodies, velocities by finite
differences over the control step, the last step's repeated: `_motion_frames_to_init_states`). The states
go into a ring buffer of the first batch's size. While a buffer exists a reset draws from it: the
character starts in the window's newest state, its disc history is the whole window, and its clip (the
ghost's, the reference's bookkeeping) is a sampled one at time 0. Without a buffer resets are AMP's.

The disc obs holds positions relative to the newest root (xy; heading too unless global_obs), so a GSI
state stands at the origin in xy. GSI needs enable_tar_obs False and pose_termination False (the
reference's agent checks) and root_height_obs True (the root height is the third value of a step).
"""

from __future__ import annotations

import torch

from mimickit.anim.kin_char_model import KinCharModel
from mimickit.envs.amp_env import DISC_HIST_KEYS, AMPEnv
from mimickit.envs.env_config import SMPEnvConfig
from mimickit.util import torch_util as tu
from mimickit.util.errors import MimicKitError

InitStates = dict[str, torch.Tensor]
"""root_pos [B,S,3], root_rot [B,S,4], root_vel, root_ang_vel [B,S,3], joint_rot [B,S,J-1,4], dof_pos,
dof_vel [B,S,D], body_pos [B,S,J,3], body_rot [B,S,J,4]: S steps, oldest first."""


class GSIBuffer:
    """A ring of init states (capacity: the first batch's size); a push overwrites the oldest. Draws go
    through a random permutation of the capacity taken modulo the filled count, as the reference's
    ExperienceBuffer: no state repeats within one pass while the buffer is full."""

    def __init__(self, capacity: int, device: torch.device) -> None:
        self.capacity, self.device = capacity, device
        self._data: InitStates = {}
        self._head = self._count = 0
        self._perm = torch.randperm(capacity, device=device)
        self._perm_head = 0

    def __len__(self) -> int:
        return self._count

    def push(self, states: InitStates) -> None:
        n = next(iter(states.values())).shape[0]
        if n > self.capacity:
            raise MimicKitError(f"GSI: {n} samples exceed the buffer's {self.capacity} (its first batch's size)")
        if not self._data:
            self._data = {k: v.new_zeros(self.capacity, *v.shape[1:]) for k, v in states.items()}
        rows = (self._head + torch.arange(n, device=self.device)) % self.capacity
        for k, v in states.items():
            self._data[k][rows] = v
        self._head = (self._head + n) % self.capacity
        self._count = min(self._count + n, self.capacity)

    def sample(self, n: int) -> InitStates:
        idx = []
        while n > 0:
            if self._perm_head == self.capacity:
                self._perm, self._perm_head = torch.randperm(self.capacity, device=self.device), 0
            take = min(n, self.capacity - self._perm_head)
            idx.append(self._perm[self._perm_head : self._perm_head + take])
            self._perm_head += take
            n -= take
        rows = torch.cat(idx) % self._count if idx else torch.zeros(0, dtype=torch.long, device=self.device)
        return {k: v[rows] for k, v in self._data.items()}


class SMPEnv(AMPEnv):
    config: SMPEnvConfig  # type: ignore[assignment]

    def _build_sim_tensors(self, config: SMPEnvConfig) -> None:
        super()._build_sim_tensors(config)
        self._gsi_buffer: GSIBuffer | None = None
        self._gsi_reset: InitStates | None = None  # the states the reset in progress drew

    # ---------------------------------------------------------------- public
    def check_gsi_config(self) -> None:
        """One-line MimicKitError when this env's config cannot take GSI states."""
        cfg = self.config
        if cfg.enable_tar_obs:
            raise MimicKitError(f"env {cfg.env_name!r}: SMP's GSI init-state buffer requires enable_tar_obs False")
        if cfg.pose_termination:
            raise MimicKitError(f"env {cfg.env_name!r}: SMP's GSI init-state buffer requires pose_termination False")
        if not cfg.root_height_obs:
            raise MimicKitError(
                f"env {cfg.env_name!r}: SMP's GSI init-state buffer requires root_height_obs True "
                "(the root height is read from the disc obs)"
            )

    def init_gsi_buffer(self, samples: torch.Tensor) -> None:
        """Start GSI with generated disc-obs windows [B, S·step] or [B, S, step] (unnormalised, B > 0):
        a buffer of B init states; resets draw from it from now on."""
        self.check_gsi_config()
        if samples.shape[0] == 0:
            raise MimicKitError("GSI: init_gsi_buffer needs at least one sample")
        states = self.motion_frames_to_init_states(self.disc_obs_to_motion_frames(samples))
        buffer = GSIBuffer(samples.shape[0], self.device)
        buffer.push(states)
        self._gsi_buffer = buffer  # only now: a refused batch leaves the env as it was

    def add_gsi_samples(self, samples: torch.Tensor) -> None:
        """Push more windows (as `init_gsi_buffer`'s, at most its B) into the buffer, replacing the oldest."""
        if self._gsi_buffer is None:
            raise MimicKitError("GSI: add_gsi_samples before init_gsi_buffer")
        self._gsi_buffer.push(self.motion_frames_to_init_states(self.disc_obs_to_motion_frames(samples)))

    def has_gsi_buffer(self) -> bool:
        return self._gsi_buffer is not None

    def get_gsi_buffer(self) -> GSIBuffer | None:
        return self._gsi_buffer

    def disc_obs_to_motion_frames(self, samples: torch.Tensor) -> torch.Tensor:
        """Disc-obs windows [B, S·step] or [B, S, step] → motion frames [B, S, 6 + D]."""
        s = self._num_disc_obs_steps
        dim = self._disc_obs_space.shape[0]
        if samples.shape[-1] == dim and samples.dim() == 2:
            samples = samples.reshape(samples.shape[0], s, dim // s)
        if samples.dim() != 3 or tuple(samples.shape[1:]) != (s, dim // s):
            raise MimicKitError(
                f"GSI: samples of shape {tuple(samples.shape)}; "
                f"this env's disc obs are [B, {dim}] or [B, {s}, {dim // s}]"
            )
        return disc_obs_to_motion_frames(samples.to(self.device, torch.float32), self._char_model)

    def motion_frames_to_init_states(self, frames: torch.Tensor) -> InitStates:
        """Motion frames [B, S, 6 + D] → init states (`InitStates`), velocities over the control step."""
        return motion_frames_to_init_states(frames, self._char_model, self._engine.get_timestep())

    # ---------------------------------------------------------------- resets
    def _draw_reset_states(self, n: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        if self._gsi_buffer is None:
            return super()._draw_reset_states(n)
        states = self._gsi_buffer.sample(n)
        self._gsi_reset = states
        ids = self._motion_lib.sample_motions(n).to(self.device)
        newest = {k: states[k][:, -1:] for k in self._frames}  # one column: enable_tar_obs is off
        return ids, torch.zeros(n, device=self.device), self._pack(newest)

    def _reset_disc_hist(self, env_ids: torch.Tensor) -> None:
        states, self._gsi_reset = self._gsi_reset, None
        if states is None:
            super()._reset_disc_hist(env_ids)
            return
        states = dict(states, body_pos=states["body_pos"][:, :, self._disc_body_ids])
        for k in DISC_HIST_KEYS:
            self._disc_hist[k][env_ids] = states[k]


def disc_obs_to_motion_frames(samples: torch.Tensor, char: KinCharModel) -> torch.Tensor:
    """Per step [..., step] → [..., 6 + D]: root position (values 0:3), root rotation as an exp map (3:9,
    tangent-normal), the DoFs of the joint rotations (9:9 + 6(J-1)); the rest (bodies, velocities) unused."""
    num_rots = char.get_num_joints() - 1
    root_rot = tu.tan_norm_to_quat(samples[..., 3:9])
    joint_rot = tu.tan_norm_to_quat(samples[..., 9 : 9 + 6 * num_rots].reshape(*samples.shape[:-1], num_rots, 6))
    return torch.cat([samples[..., 0:3], tu.quat_to_exp_map(root_rot), char.rot_to_dof(joint_rot)], dim=-1)


def motion_frames_to_init_states(frames: torch.Tensor, char: KinCharModel, dt: float) -> InitStates:
    """Motion frames [B, S, 6 + D] → `InitStates`: rotations, FK bodies, and velocities as forward
    differences over dt (step i from i to i+1; the last step repeats the one before; zero when S = 1)."""
    root_pos = frames[..., 0:3]
    root_rot = tu.exp_map_to_quat(frames[..., 3:6])
    dof_pos = frames[..., 6:]
    joint_rot = char.dof_to_rot(dof_pos)
    body_pos, body_rot = char.forward_kinematics(root_pos, root_rot, joint_rot)
    root_vel, root_ang_vel, dof_vel = torch.zeros_like(root_pos), torch.zeros_like(root_pos), torch.zeros_like(dof_pos)
    if frames.shape[1] > 1:
        root_vel[:, :-1] = (root_pos[:, 1:] - root_pos[:, :-1]) / dt
        drot = tu.quat_mul(root_rot[:, 1:], tu.quat_conjugate(root_rot[:, :-1]))
        root_ang_vel[:, :-1] = tu.quat_to_exp_map(drot) / dt
        dof_vel[:, :-1] = char.compute_dof_vel(joint_rot[:, :-1], joint_rot[:, 1:], dt)
        for v in (root_vel, root_ang_vel, dof_vel):
            v[:, -1] = v[:, -2]
    return {
        "root_pos": root_pos, "root_rot": root_rot, "root_vel": root_vel, "root_ang_vel": root_ang_vel,
        "joint_rot": joint_rot, "dof_pos": dof_pos, "dof_vel": dof_vel, "body_pos": body_pos, "body_rot": body_rot,
    }  # fmt: skip
