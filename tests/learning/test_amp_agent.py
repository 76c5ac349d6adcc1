"""AMP: the discriminator's losses and reward against hand-computed values, and the agent on the real
AMP env (MuJoCo humanoid, the project's demo clip): replay fill rule, rewards, checkpoint keys, a
short training run and the per-step style reward in `info["reward_terms"]`."""

from __future__ import annotations

import json
import math

import pytest
import torch

from mimickit.envs.amp_env import AMPEnv
from mimickit.envs.env_builder import build_env
from mimickit.learning import disc_util
from mimickit.learning.agent_builder import build_agent_from_config, load_agent_config
from mimickit.learning.agent_config import AMPAgentConfig
from mimickit.learning.amp_agent import AMPAgent, calc_disc_rewards, compute_disc_loss, store_disc_replay, style_rewards
from mimickit.learning.amp_model import AMPModel
from mimickit.learning.base_agent import TRAIN_STATE_KEY
from mimickit.learning.experience_buffer import ExperienceBuffer
from mimickit.learning.normalizer import Normalizer
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA_DIR
from tests.learning.conftest import disc_config_dict, first_step_info
from tests.learning.toy_env import TargetReachEnv

ENGINE = PROJECT_DATA_DIR / "engines/mujoco_engine.yaml"
AMP_ENV = PROJECT_DATA_DIR / "envs/amp_humanoid_env.yaml"
LN2, LN3 = math.log(2.0), math.log(3.0)


# ------------------------------------------------------------------ the pure functions, by hand


def test_disc_reward_by_hand():
    logits = torch.tensor([0.0, LN3, -LN3, 20.0])
    # p = 0.5, 0.75, 0.25, ≈1 → −log(1−p)·2; the last one is clamped at 1 − p = 1e-4.
    expected = torch.tensor([2 * LN2, 2 * math.log(4.0), -2 * math.log(0.75), -2 * math.log(1e-4)])
    torch.testing.assert_close(disc_util.disc_reward(logits, 2.0), expected)


def test_disc_bce_loss_by_hand():
    agent, demo = torch.tensor([0.0, LN3]), torch.tensor([LN3])
    # agent (label 0): −log(1−p) = log 2, log 4 → mean 1.5·log 2; demo (label 1): −log 0.75.
    expected = 0.5 * (1.5 * LN2 - math.log(0.75))
    assert disc_util.disc_bce_loss(agent, demo).item() == pytest.approx(expected, rel=1e-6)


def test_grad_penalty_by_hand_and_differentiable():
    x = torch.tensor([[1.0, 0.0], [2.0, 5.0]], requires_grad=True)
    linear = x @ torch.tensor([3.0, 4.0]) + 7.0  # ∇ = (3, 4): ‖∇‖² = 25 for every sample
    assert disc_util.disc_grad_penalty(linear, x).item() == pytest.approx(25.0)
    a = torch.tensor(1.5, requires_grad=True)
    x = torch.tensor([[1.0, 0.0], [2.0, 0.0]], requires_grad=True)
    quad = a * x[:, 0] ** 2 + x[:, 1]  # ∇ = (2a·x1, 1): ‖∇‖² = 4a²x1² + 1 → 10, 37
    gp = disc_util.disc_grad_penalty(quad, x)
    assert gp.item() == pytest.approx(23.5)
    gp.backward()  # d/da mean(4a²x1² + 1) = 8a·mean(x1²) = 8 · 1.5 · 2.5
    assert a.grad.item() == pytest.approx(30.0)


def test_logit_reg_and_accuracy_by_hand():
    assert disc_util.disc_logit_reg(torch.tensor([1.0, -2.0, 3.0])).item() == pytest.approx(14.0)
    agent_acc, demo_acc = disc_util.disc_accuracy(torch.tensor([-1.0, 2.0, -3.0, 0.0]), torch.tensor([1.0, -1.0, 0.5]))
    assert agent_acc.item() == pytest.approx(0.5) and demo_acc.item() == pytest.approx(2 / 3)


# ------------------------------------------------------------------ the agent on the AMP env


def amp_config(**overrides) -> AMPAgentConfig:
    cfg = disc_config_dict("AMP", disc_grad_penalty=5.0)
    cfg.update(overrides)
    return AMPAgentConfig(**cfg)


def make_agent(num_envs: int = 4, **overrides) -> tuple[AMPEnv, AMPAgent]:
    env = build_env(AMP_ENV, ENGINE, num_envs)
    agent = build_agent_from_config(amp_config(**overrides), env, "cpu")
    assert isinstance(env, AMPEnv) and isinstance(agent, AMPAgent)
    return env, agent


def test_shipped_amp_agent_yaml_has_the_reference_values():
    cfg = load_agent_config(PROJECT_DATA_DIR / "agents/amp_humanoid_agent.yaml")
    assert isinstance(cfg, AMPAgentConfig) and cfg.model.disc_net == "fc_2layers_1024units"
    assert (cfg.disc_optimizer.type, cfg.disc_optimizer.learning_rate, cfg.disc_optimizer.weight_decay) == (
        "SGD", 2.5e-4, 1e-4,
    )  # fmt: skip
    assert (cfg.disc_epochs, cfg.disc_batch_size, cfg.disc_buffer_size, cfg.disc_replay_samples) == (2, 2, 200000, 1000)
    assert (cfg.disc_logit_reg, cfg.disc_grad_penalty, cfg.disc_reward_scale) == (0.01, 5.0, 2.0)
    assert (cfg.task_reward_weight, cfg.disc_reward_weight) == (0.0, 1.0)


def disc_parts(disc_obs_size: int = 1420) -> tuple[AMPModel, Normalizer]:
    """AMP's networks and a disc obs normaliser with non-trivial statistics, without an agent or env."""
    model, norm = AMPModel(amp_config().model, 6, 2, disc_obs_size), Normalizer((disc_obs_size,), clip=10.0)
    norm.record(3.0 * torch.randn(64, disc_obs_size) + 1.0)
    norm.update()
    return model, norm


def test_replay_buffer_takes_everything_until_full_then_a_subset():
    buffer = ExperienceBuffer(amp_config().disc_buffer_size, 1, "cpu")
    totals = []
    for _ in range(6):
        store_disc_replay(buffer, torch.randn(32, 1420), replay_samples=5)  # 32 samples per iteration
        totals.append(buffer.get_total_samples())
    # Capacity 100: 32, 64, 96, then 96 < 100 so all 32 again (wrapping), then 5 per iteration.
    assert totals == [32, 64, 96, 128, 133, 138]


def test_rewards_are_the_weighted_task_and_disc_rewards():
    model, norm = disc_parts()
    disc_obs, task_r = torch.randn(32, 1420), torch.rand(8, 4)
    disc_r = calc_disc_rewards(model, norm, disc_obs, reward_scale=2.0).view(8, 4)
    with torch.no_grad():
        logits = model.eval_disc(norm.normalize(disc_obs)).view(8, 4)
    expected = -torch.log(torch.clamp_min(1.0 - torch.sigmoid(logits), 1e-4)) * 2.0
    torch.testing.assert_close(disc_r, expected)
    torch.testing.assert_close(calc_disc_rewards(model, norm, disc_obs, 2.0, eval_batch_size=5).view(8, 4), disc_r)
    reward, info = style_rewards(task_r, disc_r, task_weight=0.5, disc_weight=2.0)
    torch.testing.assert_close(reward, 0.5 * task_r + 2.0 * expected)
    assert info["disc_reward_mean"] == pytest.approx(expected.mean().item(), rel=1e-5)
    assert info["disc_reward_std"] == pytest.approx(expected.std().item(), rel=1e-5)


def test_disc_loss_is_bce_plus_weighted_penalties():
    model, norm = disc_parts()
    agent_obs, demo_obs = torch.randn(12, 1420), torch.randn(6, 1420)  # a batch of 6 and as many replayed
    info = compute_disc_loss(model, norm, agent_obs, demo_obs, logit_reg=0.01, grad_penalty=5.0)
    agent_x = norm.normalize(agent_obs).requires_grad_(True)
    demo_x = norm.normalize(demo_obs).requires_grad_(True)
    agent_logit, demo_logit = model.eval_disc(agent_x), model.eval_disc(demo_x)
    gp = 0.5 * (disc_util.disc_grad_penalty(demo_logit, demo_x) + disc_util.disc_grad_penalty(agent_logit, agent_x))
    reg = dict(model.named_parameters())["_disc_logits.weight"].square().sum()
    expected = disc_util.disc_bce_loss(agent_logit, demo_logit) + 5.0 * gp + 0.01 * reg
    assert info["disc_loss"].item() == pytest.approx(expected.item(), rel=1e-5)
    assert info["disc_grad_penalty"].item() == pytest.approx(gp.item(), rel=1e-5)
    assert info["disc_logit_loss"].item() == pytest.approx(reg.item(), rel=1e-5)
    assert info["disc_agent_logit"].item() == pytest.approx(agent_logit.mean().item(), rel=1e-5)
    no_reg = compute_disc_loss(model, norm, agent_obs, demo_obs, logit_reg=0.0, grad_penalty=5.0)
    assert "disc_logit_loss" not in no_reg
    assert no_reg["disc_loss"].item() == pytest.approx(expected.item() - 0.01 * reg.item(), rel=1e-5)


@pytest.mark.slow
def test_training_separates_agent_from_demo_and_logs_the_style_reward(tmp_path):
    env, agent = make_agent()
    assert env.reward_weights == {"task": 0.0, "disc": 1.0}
    agent.train_model(4 * 32, tmp_path)
    rows = [json.loads(line) for line in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    for row in rows:
        assert row["reward_terms.disc"] == pytest.approx(row["disc_reward_mean"], rel=1e-4)
        assert row["reward_terms.task"] == 0.0 and row["train_return"] == 0.0
    last = rows[-1]
    assert last["disc_agent_logit"] < last["disc_demo_logit"]
    assert 0.5 * (last["disc_agent_acc"] + last["disc_demo_acc"]) > 0.6
    state = torch.load(tmp_path / "model.pt", weights_only=True)
    assert {k for k in state if "disc" in k} == {
        "_disc_obs_norm._count", "_disc_obs_norm._mean", "_disc_obs_norm._std",
        "_model._disc_layers.0.weight", "_model._disc_layers.0.bias",
        "_model._disc_layers.2.weight", "_model._disc_layers.2.bias",
        "_model._disc_logits.weight", "_model._disc_logits.bias",
    }  # fmt: skip
    assert set(state[TRAIN_STATE_KEY]["optimizers"]) == {"actor", "critic", "disc"}
    assert state["_disc_obs_norm._count"].item() == 2 * 4 * 32, "agent and demo disc obs of 4 iterations"

    # Loaded, the agent scores a step as the one that saved it (the env's style reward is its disc's).
    fresh_env, fresh = make_agent()
    fresh.load(tmp_path / "model.pt")
    reward = first_step_info(fresh_env, fresh)["reward_terms"]["disc"]
    torch.testing.assert_close(reward, first_step_info(env, agent)["reward_terms"]["disc"])
    assert bool((reward > 0).all())


def test_amp_on_an_env_without_disc_obs_is_one_clear_error():
    with pytest.raises(MimicKitError, match="needs an env with a discriminator observation"):
        build_agent_from_config(amp_config(), TargetReachEnv(num_envs=2), "cpu")
