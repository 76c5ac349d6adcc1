"""ASE: the latent, encoder and diversity functions against hand-computed values, and the agent on the
real ASE env (MuJoCo humanoid, the project's demo clip): sizes, latent resampling, the agent's encoder
reward / losses against the pure functions, default-pose resets."""

from __future__ import annotations

import math

import pytest
import torch

from mimickit.envs.ase_env import ASEEnv
from mimickit.envs.base_env import DoneFlags
from mimickit.envs.env_builder import build_env
from mimickit.learning import ase_util
from mimickit.learning.agent_builder import build_agent_from_config, load_agent_config
from mimickit.learning.agent_config import ASEAgentConfig
from mimickit.learning.ase_agent import ASEAgent, calc_enc_rewards, compute_diversity_loss, compute_enc_loss
from mimickit.learning.ase_model import ASEModel
from mimickit.learning.normalizer import Normalizer
from mimickit.util.paths import PROJECT_DATA_DIR

ENGINE = PROJECT_DATA_DIR / "engines/mujoco_engine.yaml"
ASE_ENV = PROJECT_DATA_DIR / "envs/ase_humanoid_env.yaml"
ASE_AGENT = PROJECT_DATA_DIR / "agents/ase_humanoid_agent.yaml"
S2 = math.sqrt(0.5)


# ------------------------------------------------------------------ the pure functions, by hand


def test_sample_latents_are_unit_vectors():
    z = ase_util.sample_latents(1000, 64)
    assert z.shape == (1000, 64)
    torch.testing.assert_close(z.norm(dim=-1), torch.ones(1000))
    assert z.mean(0).abs().max() < 0.15, "spread over the sphere, not one direction"


def test_enc_reward_and_loss_by_hand():
    z = torch.tensor([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    pred = torch.tensor([[S2, S2], [-1.0, 0.0], [0.0, 1.0]])
    # z·ẑ = 0.7071, −1, 1 → reward max(·, 0) = 0.7071, 0, 1; loss = −mean = −(0.7071 − 1 + 1)/3.
    torch.testing.assert_close(ase_util.enc_reward(z, pred), torch.tensor([S2, 0.0, 1.0]))
    assert ase_util.enc_loss(z, pred).item() == pytest.approx(-S2 / 3, rel=1e-6)


def test_diversity_loss_by_hand():
    z = torch.tensor([[1.0, 0.0], [1.0, 0.0]])
    new_z = torch.tensor([[-1.0, 0.0], [0.0, 1.0]])  # Δz = 1, 0.5
    mean_z = torch.tensor([[0.0, 0.0], [1.0, 1.0]])
    mean_new = torch.tensor([[1.0, 1.0], [1.0, 2.0]])  # Δa = mean((1,1)²) = 1, mean((0,1)²) = 0.5
    # ratio = 1/(1+1e-5), 0.5/(0.5+1e-5) ≈ 1, 1 → target 2: (2 − ratio)² ≈ 1 each.
    r1, r2 = 1 / (1 + 1e-5), 0.5 / (0.5 + 1e-5)
    expected = 0.5 * ((2 - r1) ** 2 + (2 - r2) ** 2)
    assert ase_util.diversity_loss(mean_z, mean_new, z, new_z, 2.0).item() == pytest.approx(expected, rel=1e-6)


def test_latent_schedule_resamples_on_demand_and_when_due():
    sched = ase_util.LatentSchedule(4, 64, time_min=1.0, time_max=5.0, device=torch.device("cpu"))
    sched.resample(torch.arange(4), torch.zeros(4))
    z0, times = sched.latents.clone(), sched.reset_time.clone()
    torch.testing.assert_close(z0.norm(dim=-1), torch.ones(4))
    assert bool(((times >= 1.0) & (times <= 5.0)).all())
    # Resampling some envs leaves the others' latents and times alone; a new time counts from the env's.
    sched.resample(torch.tensor([2]), torch.tensor([10.0]))
    assert not torch.allclose(sched.latents[2], z0[2]) and 11.0 <= sched.reset_time[2].item() <= 15.0
    torch.testing.assert_close(sched.latents[[0, 1, 3]], z0[[0, 1, 3]])
    torch.testing.assert_close(sched.reset_time[[0, 1, 3]], times[[0, 1, 3]])
    # Due: exactly the envs whose time has reached their reset time.
    z1 = sched.latents.clone()
    env_time = torch.tensor([times[0].item(), times[1].item() - 0.01, 0.0, 99.0])
    sched.resample_due(env_time)
    changed = [not torch.allclose(sched.latents[i], z1[i]) for i in range(4)]
    assert changed == [True, False, False, True]
    assert env_time[3].item() + 1.0 <= sched.reset_time[3].item() <= env_time[3].item() + 5.0
    sched.resample_due(torch.zeros(4))  # none due: nothing drawn
    assert sched.latents[[1, 2]].equal(z1[[1, 2]])


# ------------------------------------------------------------------ the agent on the real env


def small_ase_config() -> ASEAgentConfig:
    cfg = load_agent_config(ASE_AGENT)
    assert isinstance(cfg, ASEAgentConfig)
    # Small nets and buffers: the sizes under test come from the env and latent_dim, not the widths.
    cfg.model.actor_net = cfg.model.critic_net = cfg.model.disc_net = cfg.model.enc_net = "fc_2layers_128units"
    cfg.disc_buffer_size = 1000
    cfg.steps_per_iter = 8
    return cfg


@pytest.fixture(scope="module")
def env_agent() -> tuple[ASEEnv, ASEAgent]:
    env = build_env(ASE_ENV, ENGINE, num_envs=4)
    agent = build_agent_from_config(small_ase_config(), env)
    assert isinstance(env, ASEEnv) and isinstance(agent, ASEAgent)
    return env, agent


@pytest.fixture(scope="module")
def agent(env_agent: tuple[ASEEnv, ASEAgent]) -> ASEAgent:
    return env_agent[1]


def ase_parts(state: dict[str, torch.Tensor] | None = None) -> tuple[ASEModel, Normalizer, Normalizer]:
    """ASE's networks, obs and disc obs normalisers for the humanoid's sizes (140 obs, 28 actions, 1420
    disc obs), without an agent: from an agent's `state_dict()` when given, else fresh with
    non-trivial normaliser statistics."""
    model = ASEModel(small_ase_config().model, 140, 28, 1420)
    obs_norm, disc_norm = Normalizer((140,), clip=10.0), Normalizer((1420,), clip=10.0)
    if state is None:
        for norm, size in ((obs_norm, 140), (disc_norm, 1420)):
            norm.record(2.0 * torch.randn(64, size) - 0.5)
            norm.update()
        return model, obs_norm, disc_norm
    for module, prefix in ((model, "_model."), (obs_norm, "_obs_norm."), (disc_norm, "_disc_obs_norm.")):
        module.load_state_dict({k.removeprefix(prefix): v for k, v in state.items() if k.startswith(prefix)})
    return model, obs_norm, disc_norm


def test_sizes_and_checkpoint_keys(env_agent: tuple[ASEEnv, ASEAgent]):
    env, agent = env_agent
    assert env.get_disc_obs_space().shape == (1420,)  # the reference's size: 10 steps × 142
    assert env.get_obs_space().shape == (140,) and agent.get_action_size() == 28
    assert agent.get_latents().shape == (4, 64)
    state = agent.state_dict()
    assert state["_model._actor_layers.0.weight"].shape[1] == 140 + 64
    assert state["_model._critic_layers.0.weight"].shape[1] == 140 + 64
    assert state["_model._enc_layers.0.weight"].shape[1] == 1420
    assert state["_model._enc_out.weight"].shape[0] == 64
    assert "_disc_obs_norm._mean" in state and "_model._disc_logits.weight" in state
    assert not any("latent" in k for k in state), "latents are not checkpointed"


def test_training_resamples_the_latents_of_reset_envs_and_logs_the_diversity_loss():
    """Latents held far longer than a rollout change exactly where an episode ended (seen through the
    env's done flags); held for less than a step, every env's changes after every step."""
    for hold, every_step in ((1e9, False), (0.01, True)):
        env = build_env(ASE_ENV, ENGINE, num_envs=4)
        cfg = small_ase_config()
        cfg.latent_time_max = hold  # first: the config checks max >= min on each assignment
        cfg.latent_time_min = hold
        agent = build_agent_from_config(cfg, env)
        assert isinstance(agent, ASEAgent)
        seen: list[tuple[torch.Tensor, torch.Tensor]] = []  # (latents the step acted on, its done flags)
        real_step = env.step

        def step(action: torch.Tensor, real_step=real_step, agent=agent, seen=seen):
            latents = agent.get_latents().clone()
            out = real_step(action)
            seen.append((latents, out[2].clone()))
            return out

        env.step = step
        agent.start_training()
        info = agent.train_iteration()
        assert info is not None and info.info["diversity_loss"] > 0
        for (z, done), (z_next, _) in zip(seen, seen[1:], strict=False):
            changed = ~torch.isclose(z, z_next).all(-1)
            expected = torch.ones(4, dtype=torch.bool) if every_step else done != DoneFlags.NULL.value
            assert torch.equal(changed, expected), (hold, done)
        torch.testing.assert_close(agent.get_latents().norm(dim=-1), torch.ones(4))


def test_enc_reward_and_losses_match_the_functions():
    torch.manual_seed(0)
    model, obs_norm, disc_norm = ase_parts()
    disc_obs = torch.randn(6, 1420)
    z = ase_util.sample_latents(6, 64)
    pred = model.eval_enc(disc_norm.normalize(disc_obs))
    torch.testing.assert_close(pred.norm(dim=-1), torch.ones(6))
    cos = (z * pred).sum(-1)
    torch.testing.assert_close(calc_enc_rewards(model, disc_norm, disc_obs, z), cos.clamp_min(0).detach())
    torch.testing.assert_close(calc_enc_rewards(model, disc_norm, disc_obs, z, eval_batch_size=4), cos.clamp_min(0))
    loss = compute_enc_loss(model, disc_norm, disc_obs, z)
    assert loss.item() == pytest.approx(-cos.mean().item(), rel=1e-5, abs=1e-7)

    batch = {"obs": torch.randn(6, 140), "latent": z, "rand_action_mask": torch.ones(6)}
    torch.manual_seed(1)
    div = compute_diversity_loss(model, obs_norm, batch, target=1.0)
    torch.manual_seed(1)
    new_z = ase_util.sample_latents(6, 64)
    mu = model.eval_actor(torch.cat([obs_norm.normalize(batch["obs"]), z], -1)).mode
    mu_new = model.eval_actor(torch.cat([obs_norm.normalize(batch["obs"]), new_z], -1)).mode
    d_a = (mu_new - mu).square().mean(-1)
    d_z = 0.5 - 0.5 * (new_z * z).sum(-1)
    expected = (1.0 - d_a / (d_z + 1e-5)).square().mean()
    assert div.item() == pytest.approx(expected.item(), rel=1e-5)
    # The loss reaches the actor: its gradient moves the actor's weights (none detached on the way).
    div.backward()
    grads = [p.grad for p in model.get_actor_params() if p.grad is not None]
    assert grads and sum(float(g.abs().sum()) for g in grads) > 0.0


def test_env_reports_the_enc_reward_of_the_current_latents(env_agent: tuple[ASEEnv, ASEAgent]):
    env, agent = env_agent
    agent.start_training()
    _, _, _, info = env.step(torch.zeros(4, agent.get_action_size()))
    model, _, disc_norm = ase_parts(agent.state_dict())
    expected = calc_enc_rewards(model, disc_norm, info["disc_obs"], agent.get_latents())
    torch.testing.assert_close(info["reward_terms"]["enc"], expected)
    assert env.reward_weights == {"task": 0.0, "disc": 0.5, "enc": 0.5}


def test_default_reset_prob_puts_envs_in_the_init_pose():
    env = build_env(ASE_ENV, ENGINE, num_envs=16)
    assert isinstance(env, ASEEnv) and env.config.init_pose is not None
    init_root_pos = torch.tensor(env.config.init_pose[:3]).expand(16, -1)
    env.config.default_reset_prob = 1.0
    env.reset()
    torch.testing.assert_close(env.engine.get_root_pos(env.get_char_id()), init_root_pos)
    env.config.default_reset_prob = 0.0
    env.reset()
    assert not torch.allclose(env.engine.get_root_pos(env.get_char_id()), init_root_pos)


def test_encoder_output_layer_starts_uniform_in_a_tenth(agent: ASEAgent):
    """`_enc_out` weights ~ U(−0.1, 0.1) and bias 0, as in the reference. PyTorch's default for its 64
    inputs would be U(±1/√64 = ±0.125): the largest of 64 × 64 draws and their spread tell them apart."""
    state = agent.state_dict()
    w, b = state["_model._enc_out.weight"], state["_model._enc_out.bias"]
    assert w.shape == (64, 64)
    assert 0.095 < float(w.abs().max()) <= 0.1
    assert abs(float(w.std()) - 0.1 / math.sqrt(3)) < 0.003  # a uniform's std: half-width / √3
    assert torch.count_nonzero(b) == 0


def _actor_batch(mask: list[float]) -> dict[str, torch.Tensor]:
    """A hand-made actor minibatch of len(mask) rows, `rand_action_mask` = mask."""
    g = torch.Generator().manual_seed(3)
    obs = torch.randn(len(mask), 140, generator=g)
    return {"obs": obs, "latent": ase_util.sample_latents(len(mask), 64), "rand_action_mask": torch.tensor(mask)}


def _diversity(parts: tuple[ASEModel, Normalizer, Normalizer], batch: dict[str, torch.Tensor]) -> float:
    torch.manual_seed(7)  # the same new latents z′ for each call
    # Target 0: the loss is mean (Δa/Δz)², which moves with every row it reads (with the target 1 it
    # stays within 1e-6 of 1 for an untrained actor, whose action means hardly depend on z).
    return float(compute_diversity_loss(parts[0], parts[1], batch, target=0.0).detach())


def test_diversity_loss_uses_only_the_exploring_rows():
    parts = ase_parts()
    mask = [1.0, 0.0, 1.0, 1.0, 0.0, 1.0]
    batch = _actor_batch(mask)
    loss = _diversity(parts, batch)

    # It is the loss of the four exploring rows alone.
    rows = torch.tensor(mask) == 1.0
    alone = _diversity(parts, {k: v[rows] for k, v in batch.items()})
    assert loss > 0 and loss == pytest.approx(alone, rel=1e-6, abs=0)

    # A non-exploring row's obs and latent change nothing; an exploring row's do.
    for row, changes in ((1, False), (4, False), (2, True)):
        other = {k: v.clone() for k, v in batch.items()}
        other["obs"][row] += 3.0
        other["latent"][row] = -other["latent"][row]
        assert (_diversity(parts, other) != loss) == changes, row  # the same rows in: bit for bit the same

    # Every row exploring: all six count (the loss differs from the four rows').
    assert _diversity(parts, _actor_batch([1.0] * 6)) != pytest.approx(loss, rel=1e-3, abs=0)
