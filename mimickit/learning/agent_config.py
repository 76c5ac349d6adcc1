"""Typed configs of the agents (the reference's agent yaml fields and defaults).

The reference's agent yamls are the format. An unknown key, a wrong type or a missing required key is
one `MimicKitError` naming the file and the key; numbers written like `1e-4` are numbers. Batch sizes
(`actor_batch_size`, `critic_batch_size`) are in units of `num_envs`, as in the reference.

Adding an agent: write its config class here and its agent class in its own module, then add one line
to `AGENTS` in `agent_builder` (name → config class, "module:Class"); nothing else names agents. This
module imports no agent: the agents import their configs from it.
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import Field, model_validator

from mimickit.util.config import ConfigModel

NetName = Literal[
    "fc_2layers_128units",
    "fc_2layers_256units",
    "fc_2layers_512units",
    "fc_2layers_1024units",
    "fc_3layers_1024units",
]
StdType = Literal["FIXED", "CONSTANT", "VARIABLE"]

# Bounds on numbers that size a buffer or a loop, so one mistyped value is an error, not a giant
# allocation or an iteration that never ends (each is 100x or more what a shipped yaml uses).
MAX_STEPS_PER_ITER = 10_000
MAX_EPOCHS = 1_000
MAX_TEST_EPISODES = 10_000_000
MAX_DISC_BUFFER = 2_000_000  # disc obs rows; the humanoid's 200,000 take about 1.1 GB
MAX_LATENT_DIM = 4_096
MAX_DIFFUSION_STEPS = 64  # noise levels an SMP reward evaluates the prior at (the reference's: 3)


class OptimizerConfig(ConfigModel):
    type: Literal["SGD", "Adam"]
    """SGD (momentum 0.9) or Adam (implemented as AdamW, as the reference)."""
    learning_rate: float = Field(gt=0)
    weight_decay: float = Field(default=0.0, ge=0)
    grad_clip: float = Field(default=0.0, ge=0)
    """Global-norm clip; 0 disables it (no shipped yaml sets it)."""
    use_amp: bool = False
    """Accepted for compatibility with newer reference yamls; mixed precision is not implemented."""
    amp_type: Literal["fp16", "bf16"] = "fp16"


class ActorCriticModelConfig(ConfigModel):
    actor_net: NetName
    actor_init_output_scale: float = Field(default=0.01, gt=0)
    """Mean head weights start U(-s, s), so the initial policy mean is ≈ 0 (normalised units)."""
    actor_std_type: StdType = "FIXED"
    action_std: float = Field(gt=0)
    """Action noise σ in normalised action units (×half-range of the action box)."""
    critic_net: NetName


class BaseAgentConfig(ConfigModel):
    agent_name: str
    discount: float = Field(ge=0, lt=1)
    iters_per_output: int = Field(ge=1)
    """Every this many iterations: test episodes, a log.txt row and model.pt."""
    test_episodes: int = Field(ge=0, le=MAX_TEST_EPISODES)
    steps_per_iter: int = Field(ge=1, le=MAX_STEPS_PER_ITER)
    """Rollout length per iteration (rows of the experience buffer)."""
    normalizer_samples: float = Field(math.inf, ge=0, allow_inf_nan=True)
    """The observation normaliser is updated while the global sample count is below this."""
    use_mixed_precision: bool = False
    """Accepted for compatibility with older reference yamls; ignored."""


class DummyAgentConfig(BaseAgentConfig):
    agent_name: str = "Dummy"
    discount: float = 0.99
    iters_per_output: int = 1
    test_episodes: int = 0
    steps_per_iter: int = 32


class ActorCriticAgentConfig(BaseAgentConfig):
    """What PPO and AWR share: model, optimisers, rollout, critic, exploration and actor penalties."""

    model: ActorCriticModelConfig
    actor_optimizer: OptimizerConfig
    critic_optimizer: OptimizerConfig
    actor_epochs: int = Field(ge=0, le=MAX_EPOCHS)
    actor_batch_size: float = Field(gt=0)
    """Samples per actor minibatch = ceil(actor_batch_size × num_envs)."""
    critic_epochs: int = Field(ge=0, le=MAX_EPOCHS)
    critic_batch_size: float = Field(gt=0)
    """Samples per critic minibatch = ceil(critic_batch_size × num_envs)."""
    td_lambda: float = Field(ge=0, le=1)
    action_bound_weight: float
    action_entropy_weight: float
    action_reg_weight: float
    critic_eval_batch_size: int = Field(default=0, ge=0)
    """Samples per critic forward pass when building targets; 0 = all at once."""
    exp_anneal_samples: float = Field(math.inf, gt=0, allow_inf_nan=True)
    exp_prob_beg: float = Field(default=1.0, ge=0, le=1)
    exp_prob_end: float = Field(default=1.0, ge=0, le=1)
    lcp_weight: float = Field(default=0.0, ge=0)
    """The Lipschitz-constraint penalty's weight (LCP; 0: off): any actor-critic agent can take it."""


class PPOAgentConfig(ActorCriticAgentConfig):
    agent_name: Literal["PPO"] = "PPO"
    ppo_clip_ratio: float = Field(gt=0)
    norm_adv_clip: float = Field(gt=0)


class LCPAgentConfig(PPOAgentConfig):
    """The reference's LCP agent: PPO with a required `lcp_weight` (its G1 config: 0.002)."""

    agent_name: Literal["LCP"] = "LCP"  # type: ignore[assignment]
    lcp_weight: float = Field(ge=0)


class AWRAgentConfig(ActorCriticAgentConfig):
    agent_name: Literal["AWR"] = "AWR"
    awr_temp: float = Field(default=1.0, gt=0)
    a_weight_clip: float = Field(default=20.0, gt=0)


class AMPModelConfig(ActorCriticModelConfig):
    disc_net: NetName
    """Discriminator MLP; its output layer (Linear → 1 logit) starts with weights U(-1, 1)."""


class AMPAgentConfig(PPOAgentConfig):
    """PPO plus a discriminator that scores the env's disc obs against the clips'."""

    agent_name: Literal["AMP"] = "AMP"  # type: ignore[assignment]
    model: AMPModelConfig
    disc_optimizer: OptimizerConfig
    disc_epochs: int = Field(ge=0, le=MAX_EPOCHS)
    disc_batch_size: float = Field(gt=0)
    """Samples per discriminator minibatch = ceil(disc_batch_size × num_envs), plus as many replayed."""
    disc_buffer_size: int = Field(ge=1, le=MAX_DISC_BUFFER)
    """Capacity of the replay buffer of past agent disc obs."""
    disc_replay_samples: int = Field(ge=0, le=MAX_DISC_BUFFER)
    """Agent disc obs pushed into the full replay buffer per iteration (all of them until it is full)."""
    disc_logit_reg: float = Field(ge=0)
    """Weight of Σ w² over the logit layer's weights."""
    disc_grad_penalty: float = Field(ge=0)
    """Weight of the gradient penalty ‖∂logit/∂(normalised disc obs)‖²."""
    disc_reward_scale: float
    """r_disc = −log(max(1 − sigmoid(logit), 1e-4)) × disc_reward_scale."""
    task_reward_weight: float
    disc_reward_weight: float
    disc_eval_batch_size: int = Field(default=0, ge=0)
    """Samples per discriminator forward pass when computing rewards; 0 = all at once."""


class ADDAgentConfig(AMPAgentConfig):
    """AMP's fields: the discriminator scores the difference reference − agent of the env's
    ADD disc obs; a zero difference is its only positive sample."""

    agent_name: Literal["ADD"] = "ADD"  # type: ignore[assignment]


class ASEModelConfig(AMPModelConfig):
    enc_net: NetName
    """Encoder MLP on the normalised disc obs; its output layer predicts the latent (unit-normalised)."""
    latent_dim: int = Field(ge=1, le=MAX_LATENT_DIM)
    """Size of the skill latent z (humanoid: 64); actor and critic take [obs, z]."""


class ASEAgentConfig(AMPAgentConfig):
    """AMP plus skill latents, an encoder that recovers them from the disc obs and a diversity loss."""

    agent_name: Literal["ASE"] = "ASE"  # type: ignore[assignment]
    model: ASEModelConfig
    enc_optimizer: OptimizerConfig
    latent_time_min: float = Field(ge=0)
    """Seconds a latent is kept at least (the env's time is checked after every step)."""
    latent_time_max: float = Field(ge=0)
    enc_epochs: int = Field(ge=0, le=MAX_EPOCHS)
    enc_batch_size: float = Field(gt=0)
    """Samples per encoder minibatch = ceil(enc_batch_size × num_envs)."""
    enc_reward_weight: float
    """r = task_reward_weight · r_env + disc_reward_weight · r_disc + enc_reward_weight · max(z·ẑ, 0)."""
    diversity_weight: float = Field(ge=0)
    diversity_tar: float
    enc_eval_batch_size: int = Field(default=0, ge=0)
    """Samples per encoder forward pass when computing rewards; 0 = all at once."""

    @model_validator(mode="after")
    def _latent_times_ordered(self) -> ASEAgentConfig:
        if self.latent_time_max < self.latent_time_min:
            raise ValueError("latent_time_max must be >= latent_time_min")
        return self


class SMPAgentConfig(PPOAgentConfig):
    """PPO whose reward mixes the task's with a motion prior's: r = task_reward_weight · r_task +
    smp_reward_weight · r_smp, r_smp = exp(−sds_loss_scale · mean_t(SDS loss_t / running mean |loss_t|))
    · smp_reward_scale, the SDS losses at `diffusion_steps` of the frozen TinyMDM prior on the env's disc
    obs. `enable_gsi`: resets start from states the prior generates (generative state initialisation)."""

    agent_name: Literal["SMP"] = "SMP"  # type: ignore[assignment]
    smp_prior_cfg: str
    """The prior's config (`diffusion_config.yaml` of `mimickit train-prior`, or a data/priors/ yaml)."""
    smp_prior_model: str
    """The prior's weights (`model.pt` of `mimickit train-prior`)."""
    smp_eval_batch_size: int = Field(ge=1)
    """Samples per prior evaluation when computing rewards."""
    sds_loss_scale: float
    smp_reward_scale: float = 1.0
    diffusion_steps: list[int] = Field(min_length=1, max_length=MAX_DIFFUSION_STEPS)
    """Noise levels t the SDS loss is evaluated at, each below the prior's T."""
    sds_normalizer_samples: float = Field(default=math.inf, ge=0)
    """Samples after which the SDS losses' running mean |loss| stops updating."""
    task_reward_weight: float
    smp_reward_weight: float
    enable_gsi: bool = False
    gsi_iters: int = Field(default=50, ge=1)
    """Iterations between refills of the GSI buffer (`gsi_regen_num_motions` new states each)."""
    gsi_sampler: Literal["ddpm", "ddim"] = "ddpm"
    gsi_inference_steps: int = Field(default=10, ge=1, le=MAX_EPOCHS)
    """Denoising steps of the ddim sampler (ddpm takes all of the prior's T)."""
    gsi_buffer_size: int = Field(default=4096, ge=1, le=MAX_DISC_BUFFER)
    gsi_regen_num_motions: int = Field(default=1024, ge=1, le=MAX_DISC_BUFFER)
    gsi_batch_size: int = Field(default=256, ge=1, le=MAX_DISC_BUFFER)
    critic_loss_weight: Literal[1.0] = 1.0
    """In the reference's SMP yamls, never read by its code: accepted as 1.0 (the critic loss unweighted) only."""

    @model_validator(mode="after")
    def _gsi_sizes_ordered(self) -> SMPAgentConfig:
        if self.gsi_buffer_size < self.gsi_regen_num_motions:
            raise ValueError("gsi_buffer_size must be >= gsi_regen_num_motions")
        if self.gsi_regen_num_motions < self.gsi_batch_size:
            raise ValueError("gsi_regen_num_motions must be >= gsi_batch_size")
        return self
