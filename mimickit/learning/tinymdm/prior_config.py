"""The prior's yaml (the reference's `tools/diffusion_model/config/tinymdm_*.yaml` keys), validated.

The model's keys come first, then the training loop's, then the data's. `input_dim` / `input_channel`
are filled in by training (disc obs size of one window and of one frame) and written to the run's
`diffusion_config.yaml`; a reference-trained config lacks them, and its user passes `input_dim`.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from mimickit.learning.tinymdm.arch import MAX_SEQ_LEN
from mimickit.util.config import ConfigModel
from mimickit.util.errors import MimicKitError

MAX_ITERATIONS = 100_000_000
MAX_BATCH = 1 << 20


class PriorConfig(ConfigModel):
    model_name: str = "tiny_mdm"
    arch_name: Literal["DiT", "CondDiT"]
    T: int = Field(ge=1, le=10_000)
    """Diffusion steps of training (the noise schedule's length)."""
    loss_type: Literal["l1", "l2"]
    estimate_mode: Literal["epsilon", "sample", "v_prediction"]
    """What the denoiser predicts (diffusers' prediction_type)."""
    noise_schedule_mode: Literal["linear", "scaled_linear", "squaredcos_cap_v2", "sigmoid"]
    """diffusers' beta_schedule."""
    num_layers: int = Field(ge=1, le=64)
    num_attention_heads: int = Field(4, ge=1, le=64)
    attention_head_dim: int = Field(64, ge=1, le=1024)
    dropout: float = Field(0.0, ge=0.0, lt=1.0)
    num_class: int = Field(0, ge=0, le=100_000)
    """Class labels of CondDiT (0: unconditioned)."""
    cfg_dropout: float = Field(0.0, ge=0.0, lt=1.0)
    """Probability of dropping a label in training (classifier-free guidance)."""

    model_ema: bool = False
    model_ema_decay: float | None = Field(None, ge=0.0, le=1.0)
    model_ema_steps: int | None = Field(None, ge=1)
    model_ema_update_after: int | None = Field(None, ge=0)

    normalizer_std_clip: float = Field(gt=0)
    """Smallest std of the per-feature normaliser (the reference's 0.2 keeps near-constant features tame)."""

    device: str = "cpu"
    batch_size: int = Field(ge=1, le=MAX_BATCH)
    lr: float = Field(gt=0)
    num_iterations: int = Field(ge=1, le=MAX_ITERATIONS)
    num_samples_stat: int = Field(10_000, ge=1, le=10_000_000)
    """Windows drawn once to fit the normaliser."""
    output_iter: int = Field(2_000, ge=1)
    """Iterations between loss prints and model saves."""
    grad_clip_norm: float = Field(1.0, gt=0)

    env_config: str
    """The env yaml whose disc obs the prior models (num_disc_obs_steps, global_obs, key_bodies, ...)."""
    motion_file: str
    """A clip (.pkl) or dataset yaml: the windows are drawn from it."""
    control_freq: int = Field(ge=1, le=10_000)
    """Frames per second of a window (the env's control rate)."""
    master_port: str | None = None
    """Unused (the reference's distributed-training port), accepted so its configs load."""

    input_dim: int | None = Field(None, ge=1)
    input_channel: int | None = Field(None, ge=1)

    @model_validator(mode="after")
    def _ema_fields(self) -> PriorConfig:
        missing = [
            k for k in ("model_ema_decay", "model_ema_steps", "model_ema_update_after") if getattr(self, k) is None
        ]
        if self.model_ema and missing:
            raise ValueError(f"model_ema: True needs {', '.join(missing)}")
        return self


def check_window(num_disc_obs_steps: int, input_dim: int) -> int:
    """The per-frame size C of a window of input_dim = num_disc_obs_steps·C features."""
    if num_disc_obs_steps > MAX_SEQ_LEN:
        raise MimicKitError(f"num_disc_obs_steps {num_disc_obs_steps} > {MAX_SEQ_LEN}, the DiT's longest window")
    if input_dim % num_disc_obs_steps:
        raise MimicKitError(f"input_dim {input_dim} is not a multiple of num_disc_obs_steps {num_disc_obs_steps}")
    return input_dim // num_disc_obs_steps
