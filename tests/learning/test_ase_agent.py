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
from mimickit.learning.agent_builder import build_agent_from_config
from mimickit.learning.agent_config import ASEAgentConfig, load_agent_config
from mimickit.learning.ase_agent import ASEAgent
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


# ------------------------------------------------------------------ the agent on the real env


@pytest.fixture(scope="module")
def agent() -> ASEAgent:
    env = build_env(ASE_ENV, ENGINE, num_envs=4)
    cfg = load_agent_config(ASE_AGENT)
    assert isinstance(cfg, ASEAgentConfig)
    # Small nets and buffers: the sizes under test come from the env and latent_dim, not the widths.
    cfg.model.actor_net = cfg.model.critic_net = cfg.model.disc_net = cfg.model.enc_net = "fc_2layers_128units"
    cfg.disc_buffer_size = 1000
    cfg.steps_per_iter = 8
    agent = build_agent_from_config(cfg, env)
    assert isinstance(agent, ASEAgent)
    return agent


def test_sizes_and_checkpoint_keys(agent: ASEAgent):
    env = agent._env
    assert isinstance(env, ASEEnv)
    assert env.get_disc_obs_space().shape == (1420,)  # the reference's size: 10 steps × 142
    assert env.get_obs_space().shape == (140,)
    assert agent.get_latents().shape == (4, 64)
    state = agent.state_dict()
    assert state["_model._actor_layers.0.weight"].shape[1] == 140 + 64
    assert state["_model._critic_layers.0.weight"].shape[1] == 140 + 64
    assert state["_model._enc_layers.0.weight"].shape[1] == 1420
    assert state["_model._enc_out.weight"].shape[0] == 64
    assert "_disc_obs_norm._mean" in state and "_model._disc_logits.weight" in state
    assert not any("latent" in k for k in state), "latents are not checkpointed"


def test_latents_resampled_on_reset_and_on_schedule(agent: ASEAgent):
    env = agent._env
    agent._reset_envs()
    z0 = agent.get_latents().clone()
    torch.testing.assert_close(z0.norm(dim=-1), torch.ones(4))
    times = agent._latent_reset_time.clone()
    assert bool(((times >= 0.0) & (times <= 5.0)).all())

    # A done env gets a new latent; the others keep theirs while their time has not come.
    agent._latent_reset_time[:] = 1e9
    obs, info = env.reset()
    done = torch.full((4,), DoneFlags.NULL.value, dtype=torch.int64)
    done[2] = DoneFlags.FAIL.value
    agent._reset_done_envs(obs, info, done)
    z1 = agent.get_latents().clone()
    assert not torch.allclose(z1[2], z0[2])
    torch.testing.assert_close(z1[[0, 1, 3]], z0[[0, 1, 3]])

    # An env whose hold time has run out gets a new latent after the next step, with a new reset time.
    agent._latent_reset_time[:] = 1e9
    agent._latent_reset_time[1] = 0.0
    env.step(torch.zeros(4, agent.get_action_size()))
    agent._reset_done_envs(obs, info, torch.full((4,), DoneFlags.NULL.value, dtype=torch.int64))
    z2 = agent.get_latents()
    assert not torch.allclose(z2[1], z1[1])
    torch.testing.assert_close(z2[[0, 2, 3]], z1[[0, 2, 3]])
    t = env.get_env_time(torch.tensor([1]))
    assert t.item() <= agent._latent_reset_time[1].item() <= t.item() + 5.0
    torch.testing.assert_close(z2.norm(dim=-1), torch.ones(4))


def test_agent_enc_reward_and_losses_match_the_functions(agent: ASEAgent):
    torch.manual_seed(0)
    disc_obs = torch.randn(6, 1420)
    z = ase_util.sample_latents(6, 64)
    pred = agent._model.eval_enc(agent._disc_obs_norm.normalize(disc_obs))
    torch.testing.assert_close(pred.norm(dim=-1), torch.ones(6))
    cos = (z * pred).sum(-1)
    torch.testing.assert_close(agent._calc_enc_rewards(disc_obs, z), cos.clamp_min(0).detach())
    loss = agent._compute_enc_loss({"disc_obs": disc_obs, "latent": z})["enc_loss"]
    assert loss.item() == pytest.approx(-cos.mean().item(), rel=1e-5, abs=1e-7)

    obs = torch.randn(6, 140)
    torch.manual_seed(1)
    div = agent._compute_diversity_loss(obs, z)
    torch.manual_seed(1)
    new_z = ase_util.sample_latents(6, 64)
    mu = agent._model.eval_actor(torch.cat([agent._obs_norm.normalize(obs), z], -1)).mode
    mu_new = agent._model.eval_actor(torch.cat([agent._obs_norm.normalize(obs), new_z], -1)).mode
    d_a = (mu_new - mu).square().mean(-1)
    d_z = 0.5 - 0.5 * (new_z * z).sum(-1)
    expected = (1.0 - d_a / (d_z + 1e-5)).square().mean()
    assert div.item() == pytest.approx(expected.item(), rel=1e-5)
    # The loss reaches the actor: its gradient moves the actor's weights (none detached on the way).
    agent._model.zero_grad()
    div.backward()
    grads = [p.grad for p in agent._model.parameters() if p.grad is not None]
    assert grads and sum(float(g.abs().sum()) for g in grads) > 0.0


def test_env_reports_the_enc_reward_of_the_current_latents(agent: ASEAgent):
    env = agent._env
    agent._reset_envs()
    _, _, _, info = env.step(torch.zeros(4, agent.get_action_size()))
    expected = agent._calc_enc_rewards(info["disc_obs"], agent.get_latents())
    torch.testing.assert_close(info["reward_terms"]["enc"], expected)
    assert env.reward_weights == {"task": 0.0, "disc": 0.5, "enc": 0.5}


def test_default_reset_prob_puts_envs_in_the_init_pose():
    env = build_env(ASE_ENV, ENGINE, num_envs=16)
    env.config.default_reset_prob = 1.0
    env.reset()
    root = env._char_state()["root_pos"]
    torch.testing.assert_close(root, env._init_root_pos.expand(16, -1))
    env.config.default_reset_prob = 0.0
    env.reset()
    assert not torch.allclose(env._char_state()["root_pos"], env._init_root_pos.expand(16, -1))


def test_encoder_output_layer_starts_uniform_in_a_tenth(agent: ASEAgent):
    """`_enc_out` weights ~ U(−0.1, 0.1) and bias 0, as in the reference. PyTorch's default for its 64
    inputs would be U(±1/√64 = ±0.125): the largest of 64 × 64 draws and their spread tell them apart."""
    state = agent.state_dict()
    w, b = state["_model._enc_out.weight"], state["_model._enc_out.bias"]
    assert w.shape == (64, 64)
    assert 0.095 < float(w.abs().max()) <= 0.1
    assert abs(float(w.std()) - 0.1 / math.sqrt(3)) < 0.003  # a uniform's std: half-width / √3
    assert torch.count_nonzero(b) == 0


def _actor_batch(agent: ASEAgent, mask: list[float]) -> dict[str, torch.Tensor]:
    """A hand-made actor minibatch of len(mask) rows, `rand_action_mask` = mask."""
    n, a = len(mask), agent.get_action_size()
    g = torch.Generator().manual_seed(3)
    obs = torch.randn(n, 140, generator=g)
    return {
        "obs": obs, "norm_obs": agent._obs_norm.normalize(obs), "latent": ase_util.sample_latents(n, 64),
        "norm_action": torch.randn(n, a, generator=g), "a_logp": torch.randn(n, generator=g),
        "adv": torch.randn(n, generator=g), "rand_action_mask": torch.tensor(mask),
    }  # fmt: skip


def _diversity(agent: ASEAgent, batch: dict[str, torch.Tensor]) -> float:
    torch.manual_seed(7)  # the same new latents z′ for each call
    info = agent._compute_actor_loss(batch)
    assert info is not None
    return float(info["diversity_loss"].detach())


def test_diversity_loss_uses_only_the_exploring_rows(agent: ASEAgent, monkeypatch: pytest.MonkeyPatch):
    assert agent.config.diversity_weight != 0
    # Target 0: the loss is mean (Δa/Δz)², which moves with every row it reads (with the target 1 it
    # stays within 1e-6 of 1 for this untrained actor, whose action means hardly depend on z).
    monkeypatch.setattr(agent.config, "diversity_tar", 0.0)
    mask = [1.0, 0.0, 1.0, 1.0, 0.0, 1.0]
    batch = _actor_batch(agent, mask)
    loss = _diversity(agent, batch)

    # It is the loss of the four exploring rows alone.
    rows = torch.tensor(mask) == 1.0
    torch.manual_seed(7)
    alone = agent._compute_diversity_loss(batch["obs"][rows], batch["latent"][rows])
    assert loss > 0 and loss == pytest.approx(float(alone.detach()), rel=1e-6, abs=0)

    # A non-exploring row's obs and latent change nothing; an exploring row's do.
    for row, changes in ((1, False), (4, False), (2, True)):
        other = {k: v.clone() for k, v in batch.items()}
        other["obs"][row] += 3.0
        other["norm_obs"] = agent._obs_norm.normalize(other["obs"])
        other["latent"][row] = -other["latent"][row]
        assert (_diversity(agent, other) != loss) == changes, row  # the same rows in: bit for bit the same

    # Every row exploring: all six count (the loss differs from the four rows').
    assert _diversity(agent, _actor_batch(agent, [1.0] * 6)) != pytest.approx(loss, rel=1e-3, abs=0)
