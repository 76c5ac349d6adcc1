"""The prior's training data: windows of disc obs drawn from clips, as the reference's
`tools/diffusion_model/motion_prior_dataset.py`.

A window ends at a time drawn uniformly in a clip (clips drawn by weight) and holds the
num_disc_obs_steps frames at 1/control_freq apart leading up to it, oldest first (a clamped clip
repeats its first frame before 0). The features are the AMP env's `compute_disc_obs` of that history,
with the env yaml's global_obs, root_height_obs, disc_dof_vel_obs and key_bodies: the same observation the
SMP env gives the prior in training, [N, S·C].
"""

from __future__ import annotations

from pathlib import Path

import torch

from mimickit.anim.mjcf_char_model import load_char_model
from mimickit.anim.motion_lib import MotionLib
from mimickit.envs.amp_env import compute_disc_obs
from mimickit.envs.env_builder import parse_env_config
from mimickit.envs.env_config import AMPEnvConfig
from mimickit.learning.tinymdm.prior_config import PriorConfig
from mimickit.util import torch_util as tu
from mimickit.util.config import load_yaml
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA, DataPaths


def load_prior_env_config(env_file: str | Path) -> AMPEnvConfig:
    """The env yaml of a prior (either layout: fields under `env:` or at the top), validated by its
    env's config class, which must have disc obs (an AMP env or one derived from it)."""
    cfg = parse_env_config(load_yaml(env_file), env_file)
    if not isinstance(cfg, AMPEnvConfig):
        raise MimicKitError(f"{env_file}: env {cfg.env_name!r} has no disc obs (num_disc_obs_steps): not a prior's env")
    return cfg


class MotionPriorData:
    def __init__(
        self, config: PriorConfig, data_paths: DataPaths = PROJECT_DATA, device: torch.device | str = "cpu"
    ) -> None:
        self.env_file = data_paths.resolve(config.env_config)
        self.env_config = env = load_prior_env_config(self.env_file)
        self._device = torch.device(device)
        self.control_freq = config.control_freq
        self._timestep = 1.0 / config.control_freq
        self._num_disc_obs_steps = env.num_disc_obs_steps
        self._track_global_root = env.enable_tar_obs and env.global_obs
        self._char_model = load_char_model(data_paths.resolve(env.char_file), self._device)
        self._motion_lib = MotionLib(config.motion_file, self._char_model, self._device, data_paths=data_paths)
        self._key_body_ids = [self._char_model.get_body_id(name) for name in env.key_bodies]

    @property
    def num_disc_obs_steps(self) -> int:
        return self._num_disc_obs_steps

    def get_obs_dim(self) -> int:
        """Features of one window (S·C)."""
        return int(self.fetch_obs_demo(1).shape[-1])

    @torch.no_grad()
    def fetch_obs_demo(self, num_samples: int) -> torch.Tensor:
        """num_samples windows of disc obs [num_samples, S·C] (not normalised)."""
        lib, s = self._motion_lib, self._num_disc_obs_steps
        ids = lib.sample_motions(num_samples)
        end_times = lib.sample_time(ids)
        offsets = self._timestep * torch.arange(s - 1, -1, -1, device=self._device, dtype=torch.float32)
        times = (end_times.unsqueeze(-1) - offsets).flatten()
        f = lib.calc_motion_frame(ids.repeat_interleave(s), times)
        body_pos, _ = self._char_model.forward_kinematics(f.root_pos, f.root_rot, f.joint_rot)
        hist = {
            "root_pos": f.root_pos, "root_rot": f.root_rot, "root_vel": f.root_vel, "root_ang_vel": f.root_ang_vel,
            "joint_rot": f.joint_rot, "dof_vel": f.dof_vel, "body_pos": body_pos[:, self._key_body_ids],
        }  # fmt: skip
        hist = {k: v.reshape(num_samples, s, *v.shape[1:]) for k, v in hist.items()}
        if self._track_global_root:
            ref_pos = torch.zeros_like(hist["root_pos"][:, -1])
            ref_rot = tu.quat_identity((num_samples,), device=self._device)
        else:
            ref_pos, ref_rot = hist["root_pos"][:, -1], hist["root_rot"][:, -1]
        env = self.env_config
        return compute_disc_obs(ref_pos, ref_rot, hist, env.global_obs, env.root_height_obs, env.disc_dof_vel_obs)
