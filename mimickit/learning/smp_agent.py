"""Score-Matching Motion Priors, as the reference's SMP: PPO whose reward comes from a frozen diffusion prior.

Per iteration, after PPO's rollout (which also records the env's disc obs of every step, post-step):
1. the prior normalises each disc obs window and scores it with its SDS loss at each of `diffusion_steps`
   (noise it to level t, denoise one DDIM step, the squared error of the implied noise; `ESM_SDS_loss`);
2. r_smp = exp(−sds_loss_scale · mean_t(loss_t / running mean |loss_t|)) · smp_reward_scale, the running
   means (`_sds_normalizer`) from the losses of the iterations before (updated after each iteration until
   `sds_normalizer_samples`);
3. reward r = task_reward_weight · r_task + smp_reward_weight · r_smp; then PPO's targets and updates.
With `enable_gsi`, the prior also generates disc obs windows that the env turns into start states
(`SMPEnv.init_gsi_buffer`), `gsi_regen_num_motions` new ones every `gsi_iters` iterations.

The prior is a submodule (`_prior_model.*` in checkpoints, as the reference's), never trained here.
"""

from __future__ import annotations

import math
from pathlib import Path

import torch

from mimickit.envs.base_env import BaseEnv
from mimickit.envs.smp_env import SMPEnv
from mimickit.learning.agent_config import SMPAgentConfig
from mimickit.learning.normalizer import DiffNormalizer
from mimickit.learning.ppo_agent import PPOAgent
from mimickit.learning.tinymdm.prior_config import PriorConfig
from mimickit.learning.tinymdm.prior_dataset import load_prior_env_config
from mimickit.learning.tinymdm.tinymdm_model import TinyMDMModel, load_prior, resolve_prior_env_file
from mimickit.util.config import load_config
from mimickit.util.errors import MimicKitError


class SMPAgent(PPOAgent):
    config: SMPAgentConfig  # type: ignore[assignment]

    def __init__(self, config: SMPAgentConfig, env: BaseEnv, device: torch.device | str) -> None:
        super().__init__(config, env, device)
        if config.enable_gsi:
            self._smp_env.check_gsi_config()
            self._smp_env.init_gsi_buffer(self._generate_init_states(config.gsi_buffer_size))

    # ---------------------------------------------------------------- builders

    def _build_normalizers(self) -> None:
        super()._build_normalizers()
        if not isinstance(self._env, SMPEnv):
            raise MimicKitError(
                "agent SMP needs an SMP env (env_name smp, task_location, task_steering or task_dodgeball), "
                f"got {self._env.__class__.__name__}"
            )
        self._smp_env: SMPEnv = self._env
        self._sds_normalizer = DiffNormalizer((len(self.config.diffusion_steps),), device=self._device)

    def _build_model(self) -> None:
        super()._build_model()
        self._prior_model = self._load_prior()

    def _load_prior(self) -> TinyMDMModel:
        cfg, paths = self.config, self._env.data_paths
        cfg_file, model_file = paths.resolve(cfg.smp_prior_cfg), paths.resolve(cfg.smp_prior_model)
        for key, f in (("smp_prior_cfg", cfg_file), ("smp_prior_model", model_file)):
            if not f.is_file():
                raise MimicKitError(f"agent config: {key}: no file {f}")
        self._check_prior_fits(load_config(PriorConfig, cfg_file), cfg_file)
        input_dim = math.prod(self._smp_env.get_disc_obs_space().shape)
        return load_prior(cfg_file, model_file, device=self._device, input_dim=input_dim, data_paths=paths)

    def _check_prior_fits(self, prior_cfg: PriorConfig, cfg_file: Path) -> None:
        """The reference's checks: the prior was trained on disc obs made as this env makes them."""
        env_cfg, env = self._smp_env.config, self._smp_env
        prior_env = load_prior_env_config(resolve_prior_env_file(prior_cfg.env_config, cfg_file.parent, env.data_paths))
        pairs = [
            ("global_obs", prior_env.global_obs, env_cfg.global_obs),
            ("root_height_obs", prior_env.root_height_obs, env_cfg.root_height_obs),
            ("enable_tar_obs", prior_env.enable_tar_obs, env_cfg.enable_tar_obs),
            ("num_disc_obs_steps", prior_env.num_disc_obs_steps, env_cfg.num_disc_obs_steps),
            ("disc_dof_vel_obs", prior_env.disc_dof_vel_obs, env_cfg.disc_dof_vel_obs),
            ("key_bodies (count)", len(prior_env.key_bodies), len(env_cfg.key_bodies)),
            ("control_freq", prior_cfg.control_freq, round(1.0 / env.engine.get_timestep())),
        ]
        for key, prior_val, env_val in pairs:
            if prior_val != env_val:
                raise MimicKitError(f"SMP prior {cfg_file} does not fit the env: {key} {prior_val}, env {env_val}")
        for t in self.config.diffusion_steps:
            if not 0 <= t < prior_cfg.T:
                raise MimicKitError(f"agent config: diffusion_steps: {t} is outside the prior's 0..{prior_cfg.T - 1}")

    # ---------------------------------------------------------------- rollout data

    def _record_data_post_step(
        self, next_obs: torch.Tensor, reward: torch.Tensor, done: torch.Tensor, info: dict
    ) -> None:
        super()._record_data_post_step(next_obs, reward, done, info)
        self._exp_buffer.record("disc_obs", info["disc_obs"])  # after the step, before done envs are reset

    def _build_train_data(self) -> dict[str, float]:
        reward_info = self._compute_rewards()
        return {**super()._build_train_data(), **reward_info}

    def _compute_rewards(self) -> dict[str, float]:
        """Replace the stored env reward [T, N] by the weighted task + prior reward."""
        buf, cfg = self._exp_buffer, self.config
        task_r = buf.get_data_flat("reward")
        disc_obs = buf.get_data_flat("disc_obs")
        steps = self._smp_env.get_num_disc_obs_steps()
        norm_obs = self._prior_model.normalize(disc_obs.reshape(disc_obs.shape[0], steps, -1))
        smp_r, sds_loss = self._calc_smp_rewards(norm_obs.reshape(disc_obs.shape[0], -1))
        buf.set_data_flat("reward", cfg.task_reward_weight * task_r + cfg.smp_reward_weight * smp_r)
        smp_std, smp_mean = torch.std_mean(smp_r)
        loss_std, loss_mean = torch.std_mean(sds_loss)
        return {
            "smp_reward_mean": smp_mean.item(),
            "smp_reward_std": smp_std.item(),
            "sds_loss_mean": loss_mean.item(),
            "sds_loss_std": loss_std.item(),
        }

    def _calc_smp_rewards(self, norm_obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        cfg = self.config
        return calc_smp_rewards(
            self._prior_model, self._sds_normalizer, norm_obs, cfg.diffusion_steps, cfg.sds_loss_scale,
            cfg.smp_reward_scale, cfg.smp_eval_batch_size, record=self._need_sds_normalizer_update(),
        )  # fmt: skip

    def _need_sds_normalizer_update(self) -> bool:
        return self._sample_count < self.config.sds_normalizer_samples

    # ---------------------------------------------------------------- iterations

    def _train_iter(self) -> dict[str, float] | None:
        info = super()._train_iter()
        if info is None:
            return None
        if self._need_sds_normalizer_update():
            self._sds_normalizer.update()
        if self.config.enable_gsi and self._iter % self.config.gsi_iters == 0:
            self._smp_env.add_gsi_samples(self._generate_init_states(self.config.gsi_regen_num_motions))
        return info

    @torch.no_grad()
    def _generate_init_states(self, num_motions: int) -> torch.Tensor:
        """`num_motions` disc obs windows [num_motions, S, C] the prior generates (unnormalised)."""
        cfg, prior = self.config, self._prior_model
        sample = prior.sample_ema if prior.model_ema else prior.sample
        shape = self._smp_env.get_disc_obs_space().shape
        steps = self._smp_env.get_num_disc_obs_steps()
        out = []
        for start in range(0, num_motions, cfg.gsi_batch_size):
            n = min(cfg.gsi_batch_size, num_motions - start)
            norm = sample(shape, n, self._device, sampler=cfg.gsi_sampler, num_inference_steps=cfg.gsi_inference_steps)
            out.append(prior.unnormalize(norm.reshape(n, steps, -1)))
        return torch.cat(out)


@torch.no_grad()
def calc_smp_rewards(
    prior: TinyMDMModel,
    sds_normalizer: DiffNormalizer,
    norm_obs: torch.Tensor,
    diffusion_steps: list[int],
    sds_loss_scale: float,
    smp_reward_scale: float = 1.0,
    batch_size: int | None = None,
    record: bool = False,
) -> tuple[torch.Tensor, torch.Tensor]:
    """r_smp [B] and the mean SDS loss [B] of normalised disc obs [B, S·C], `batch_size` at a time:
    r_smp = exp(−sds_loss_scale · mean_t(loss_t / running mean |loss_t|)) · smp_reward_scale, the losses
    recorded into `sds_normalizer` first when `record` (its running means change only at its `update`)."""
    rewards, losses = [], []
    for batch in norm_obs.split(batch_size or len(norm_obs)):
        sds = prior.ESM_SDS_loss(batch, diffusion_steps)  # [b, len(diffusion_steps)]
        if record:
            sds_normalizer.record(sds)
        scaled = sds_normalizer.normalize(sds).mean(dim=-1)
        rewards.append(torch.exp(-scaled * sds_loss_scale) * smp_reward_scale)
        losses.append(sds.mean(dim=-1))
    return torch.cat(rewards), torch.cat(losses)
