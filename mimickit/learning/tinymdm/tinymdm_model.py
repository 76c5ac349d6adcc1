"""TinyMDMModel: the SMP motion prior, as the reference's `tinymdm/tinymdm_model.py`.

A diffusion model over windows of S = num_disc_obs_steps disc-obs frames of C features, flat [N, S·C]:
- `normalize` / `unnormalize`: per-feature mean/std of one frame (std at least `normalizer_std_clip`);
- `forward(x)`: the training loss on normalised windows x: noise at a random step t < T (diffusers'
  DDPM schedule), predict epsilon / x0 / v, l1 or l2 against it;
- `sample` / `sample_ema`: windows from noise with the DDPM (all T steps) or DDIM sampler, by the model or
  its EMA copy → normalised [N, S·C];
- `ESM_SDS_loss(x, t_lst)`: per sample and per step t of t_lst, ‖ε̂ − ε‖² / (S·C) of x noised at t with fresh
  noise ε, where ε̂ is the noise implied by the denoiser's x0 (EMA copy when there is one) → [N, len(t_lst)].
  SMP's reward is built from it: low for windows the prior finds likely.
Attributes and module names are the reference's state-dict keys (`dmodel`, `ema_dmodel`, `obs_normalizer`).
`load_prior` reads a trained prior (its `diffusion_config.yaml` and `model.pt`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import torch
import torch.nn.functional as F
from diffusers.schedulers import DDIMScheduler, DDPMScheduler
from torch import nn

from mimickit.learning.normalizer import Normalizer
from mimickit.learning.tinymdm.arch import CondTinyStableMotionDiTModel, TinyStableMotionDiTModel
from mimickit.learning.tinymdm.ema import EMA
from mimickit.learning.tinymdm.prior_config import PriorConfig, check_window
from mimickit.util.config import load_config
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA, DataPaths

Sampler = str  # "ddpm" or "ddim"


class StdClipNormalizer(Normalizer):
    """The running mean/std normaliser whose std is clamped to at least `std_clip` after each update
    (the reference's `Normalizer(..., std_clip=...)`; state keys `_count`, `_mean`, `_std`)."""

    def __init__(self, shape: tuple[int, ...], std_clip: float, device: torch.device | str = "cpu") -> None:
        super().__init__(shape, device=device)
        self.std_clip = std_clip

    def update(self) -> None:
        super().update()
        with torch.no_grad():
            self._std.clamp_(min=self.std_clip)


class ClassifierFreeSampleModel(nn.Module):
    """Classifier-free guidance around a conditioned denoiser: uncond + cfg_scale·(cond − uncond)."""

    def __init__(self, model: nn.Module) -> None:
        super().__init__()
        self.model = model

    def forward(
        self,
        x: torch.Tensor,
        timestep: torch.Tensor,
        class_labels: torch.Tensor | None = None,
        cfg_scale: float = 1.0,
        **kwargs: object,
    ) -> torch.Tensor:
        n = x.shape[0]
        drop = torch.cat([torch.zeros(n, dtype=torch.bool), torch.ones(n, dtype=torch.bool)]).to(x.device)
        labels = None if class_labels is None else torch.cat([class_labels, class_labels])
        out = self.model(
            torch.cat([x, x]), torch.cat([timestep, timestep]), class_labels=labels, force_drop_ids=drop, **kwargs
        )
        cond, uncond = out.chunk(2, dim=0)
        return uncond + cfg_scale * (cond - uncond)


class TinyMDMModel(nn.Module):
    def __init__(
        self, config: PriorConfig, input_dim: int, num_disc_obs_steps: int, device: torch.device | str | None = None
    ) -> None:
        """input_dim: features of one window (the env's disc obs size); num_disc_obs_steps: frames in it."""
        super().__init__()
        self.config = config
        self.T = config.T
        self._device = torch.device(device if device is not None else config.device)
        self.num_disc_obs_steps = num_disc_obs_steps
        self.input_dim = input_dim
        self.input_channel = check_window(num_disc_obs_steps, input_dim)
        self.estimate_mode = config.estimate_mode
        self.loss_type = config.loss_type
        self.model_ema = config.model_ema

        arch = TinyStableMotionDiTModel if config.arch_name == "DiT" else CondTinyStableMotionDiTModel
        cond = (
            {"num_class": config.num_class, "cfg_dropout": config.cfg_dropout} if config.arch_name == "CondDiT" else {}
        )
        self.dmodel = arch(
            in_channels=self.input_channel,
            num_layers=config.num_layers,
            attention_head_dim=config.attention_head_dim,
            num_attention_heads=config.num_attention_heads,
            out_channels=self.input_channel,
            dropout=config.dropout,
            **cond,
        )
        if config.model_ema:
            assert config.model_ema_decay is not None and config.model_ema_steps is not None
            assert config.model_ema_update_after is not None
            self.ema_dmodel = EMA(
                self.dmodel, config.model_ema_decay, config.model_ema_steps, config.model_ema_update_after
            )

        sched = {
            "num_train_timesteps": self.T,
            "beta_schedule": config.noise_schedule_mode,
            "prediction_type": config.estimate_mode,
            "clip_sample": False,
        }
        self.diffusion_scheduler = DDPMScheduler(**sched)
        self.ddim_scheduler = DDIMScheduler(**sched)
        self.ddim_scheduler.set_timesteps(self.T, device=self._device)
        self.diffusion_scheduler.alphas_cumprod = self.diffusion_scheduler.alphas_cumprod.to(self._device)
        self.diffusion_scheduler.timesteps = self.diffusion_scheduler.timesteps.to(self._device)

        self.obs_normalizer = StdClipNormalizer((self.input_channel,), config.normalizer_std_clip)
        self.to(self._device)

    # ---------------------------------------------------------- normaliser
    def update_normalizer(self, samples: torch.Tensor) -> None:
        """Fit the per-frame normaliser to windows samples [N, S·C] or [N, S, C]."""
        self.obs_normalizer.record(samples.reshape(-1, self.input_channel))
        self.obs_normalizer.update()

    def normalize(self, samples: torch.Tensor) -> torch.Tensor:
        """Windows [..., S, C] or [N, S·C] → the same shape, each frame normalised."""
        return self.obs_normalizer.normalize(samples.reshape(-1, self.input_channel)).reshape(samples.shape)

    def unnormalize(self, norm_samples: torch.Tensor) -> torch.Tensor:
        return self.obs_normalizer.unnormalize(norm_samples.reshape(-1, self.input_channel)).reshape(norm_samples.shape)

    # -------------------------------------------------------------- training
    def forward(self, x: torch.Tensor, timesteps: torch.Tensor | None = None, **kwargs: object) -> torch.Tensor:
        """The denoising loss (scalar) of normalised windows x [N, S·C] at timesteps [N] (random if None)."""
        sched = self.diffusion_scheduler
        if timesteps is None:
            timesteps = torch.randint(0, len(sched.timesteps), (x.shape[0],), device=x.device)
        noise = torch.randn_like(x)
        noised_x = sched.add_noise(original_samples=x, noise=noise, timesteps=timesteps)
        pred = self.dmodel(noised_x, timesteps, **kwargs)
        if self.estimate_mode == "epsilon":
            target = noise
        elif self.estimate_mode == "sample":
            target = x
        else:  # v_prediction
            target = sched.get_velocity(x, noise, timesteps)
        return F.l1_loss(pred, target) if self.loss_type == "l1" else F.mse_loss(pred, target)

    # -------------------------------------------------------------- sampling
    def _denoiser(self, use_ema: bool, cfg_scale: float = 1.0) -> nn.Module:
        denoiser: nn.Module = self.ema_dmodel if use_ema else self.dmodel
        return ClassifierFreeSampleModel(denoiser) if cfg_scale != 1.0 else denoiser

    def _scheduler(
        self, sampler: Sampler, num_inference_steps: int | None, device: torch.device | str
    ) -> DDPMScheduler | DDIMScheduler:
        if sampler == "ddpm":  # every training step; num_inference_steps is not read (as the reference)
            return self.diffusion_scheduler
        if sampler == "ddim":
            self.ddim_scheduler.set_timesteps(num_inference_steps or self.T, device=device)
            return self.ddim_scheduler
        raise MimicKitError(f"unknown sampler {sampler!r}: ddpm or ddim")

    @torch.no_grad()
    def _sample(
        self,
        use_ema: bool,
        shape: Sequence[int],
        batch_size: int,
        device: torch.device | str,
        sampler: Sampler,
        num_inference_steps: int | None,
        **kwargs: object,
    ) -> torch.Tensor:
        denoiser = self._denoiser(use_ema, float(kwargs.get("cfg_scale", 1.0)))  # type: ignore[arg-type]
        scheduler = self._scheduler(sampler, num_inference_steps, device)
        x_t = torch.randn(batch_size, *shape, device=device)
        x_0 = x_t
        for t in scheduler.timesteps:
            timestep = torch.full((batch_size,), int(t), dtype=torch.long, device=device)
            out = scheduler.step(denoiser(x_t, timestep, **kwargs), t, x_t)
            x_t, x_0 = out.prev_sample, out.pred_original_sample
        return x_0

    def sample(
        self,
        shape: Sequence[int],
        batch_size: int,
        device: torch.device | str,
        sampler: Sampler = "ddpm",
        num_inference_steps: int | None = None,
        **kwargs: object,
    ) -> torch.Tensor:
        """batch_size normalised windows [batch_size, *shape] (shape: the disc obs space's, (S·C,)), by the model."""
        return self._sample(False, shape, batch_size, device, sampler, num_inference_steps, **kwargs)

    def sample_ema(
        self,
        shape: Sequence[int],
        batch_size: int,
        device: torch.device | str,
        sampler: Sampler = "ddpm",
        num_inference_steps: int | None = None,
        **kwargs: object,
    ) -> torch.Tensor:
        """As `sample`, by the EMA copy (needs model_ema)."""
        return self._sample(True, shape, batch_size, device, sampler, num_inference_steps, **kwargs)

    # -------------------------------------------------------------- SDS loss
    def _get_epsilon(self, t: torch.Tensor, x_noised: torch.Tensor, pred_x_start: torch.Tensor) -> torch.Tensor:
        """The noise that takes pred_x_start to x_noised at steps t [N]: (x_t − √ᾱ·x0) / √(1 − ᾱ)."""
        alpha_prod_t = self.diffusion_scheduler.alphas_cumprod[t].unsqueeze(-1)
        return (x_noised - pred_x_start * alpha_prod_t**0.5) / (1 - alpha_prod_t) ** 0.5

    @torch.no_grad()
    def ESM_SDS_loss(self, norm_x_obs: torch.Tensor, t_lst: Sequence[int], **kwargs: object) -> torch.Tensor:  # noqa: N802 (the reference's name)
        """Per-sample SDS losses of normalised windows norm_x_obs [N, S·C] at each step of t_lst → [N, len(t_lst)]."""
        denoiser = self._denoiser(self.model_ema, float(kwargs.get("cfg_scale", 1.0)))  # type: ignore[arg-type]
        n, device = norm_x_obs.shape[0], norm_x_obs.device
        dims = list(range(1, norm_x_obs.dim()))
        losses = []
        for t_value in t_lst:
            t = torch.full((n,), int(t_value), dtype=torch.long, device=device)
            noise = torch.randn_like(norm_x_obs)
            noised = self.diffusion_scheduler.add_noise(norm_x_obs, noise, t)
            pred = denoiser(noised.clone(), timestep=t, **kwargs)
            x0_pred = self.ddim_scheduler.step(pred, int(t_value), noised).pred_original_sample
            eps_pred = self._get_epsilon(t, noised, x0_pred)
            losses.append(torch.mean((eps_pred - noise) ** 2, dim=dims))
        return torch.stack(losses, dim=1)


def resolve_prior_env_file(env_config: str, cfg_dir: Path, data_paths: DataPaths = PROJECT_DATA) -> Path:
    """The env yaml a prior config names: a file of that name beside the config (where training copies
    it, `env_config.yaml`) first, then the path as `data_paths` resolves it."""
    beside = cfg_dir / Path(env_config).name
    if beside.is_file():
        return beside
    path = data_paths.resolve(env_config)
    if not path.is_file():
        raise MimicKitError(f"env_config not found: {env_config}")
    return path


def load_prior(
    cfg_file: str | Path,
    model_file: str | Path,
    device: torch.device | str = "cpu",
    input_dim: int | None = None,
    data_paths: DataPaths = PROJECT_DATA,
) -> TinyMDMModel:
    """A trained prior in eval mode on device, weights frozen: its config (`diffusion_config.yaml`) and
    weights (`model.pt`, read with weights_only). input_dim defaults to the config's (written by
    `mimickit train-prior`; a reference-trained config has none: pass the env's disc obs size)."""
    from mimickit.learning.tinymdm.prior_dataset import load_prior_env_config

    cfg_file = Path(cfg_file)
    config = load_config(PriorConfig, cfg_file)
    env_cfg = load_prior_env_config(resolve_prior_env_file(config.env_config, cfg_file.parent, data_paths))
    input_dim = input_dim or config.input_dim
    if input_dim is None:
        raise MimicKitError(f"{cfg_file}: no input_dim in the config; pass the env's disc obs size")
    model = TinyMDMModel(config, input_dim, env_cfg.num_disc_obs_steps, device=device)
    try:
        state = torch.load(model_file, map_location=device, weights_only=True)
    except (OSError, RuntimeError) as e:
        raise MimicKitError(f"{model_file}: cannot read the prior's weights ({str(e).splitlines()[0][:200]})") from None
    try:
        result = model.load_state_dict(state, strict=False)
    except RuntimeError as e:  # a tensor of another shape
        raise MimicKitError(
            f"{model_file}: not a prior of {cfg_file} ({str(e).splitlines()[-1].strip()[:200]})"
        ) from None
    if result.missing_keys or result.unexpected_keys:
        raise MimicKitError(
            f"{model_file}: not a prior of {cfg_file} (missing keys {result.missing_keys[:5]},"
            f" unexpected {result.unexpected_keys[:5]})"
        )
    model.eval()
    for p in model.parameters():
        p.requires_grad_(False)
    return model
