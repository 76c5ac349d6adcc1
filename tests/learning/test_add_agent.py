"""ADD: the differential input, reward and every loss term against hand-computed values (a toy env with
2-dim disc obs and a discriminator set by hand to an affine function), the disc optimiser's weight
decay, and the agent on the real ADD env (MuJoCo humanoid, the project's demo clip): a short training
run, its metrics, normaliser and checkpoint keys."""

from __future__ import annotations

import json
import math
from collections.abc import Callable

import pytest
import torch
import torch.nn.functional as F

from mimickit.envs.add_env import ADDEnv
from mimickit.envs.base_env import BoxSpace
from mimickit.envs.env_config import load_env_configs
from mimickit.learning.add_agent import ADDAgent
from mimickit.learning.agent_builder import build_agent_from_config
from mimickit.learning.agent_config import ADDAgentConfig, load_agent_config
from mimickit.learning.base_agent import TRAIN_STATE_KEY
from mimickit.learning.normalizer import DiffNormalizer
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA_DIR
from tests.learning.conftest import ppo_config_dict
from tests.learning.toy_env import TargetReachEnv

ENGINE = PROJECT_DATA_DIR / "engines/mujoco_engine.yaml"
ADD_ENV = PROJECT_DATA_DIR / "envs/add_humanoid_env.yaml"
AMP_ENV = PROJECT_DATA_DIR / "envs/amp_humanoid_env.yaml"
DEMO_CLIP = PROJECT_DATA_DIR / "motions/humanoid_demo_squat.pkl"


class DiffToyEnv(TargetReachEnv):
    """The toy env with ADD's interface: the agent's disc obs is the point, the reference's the target."""

    def __init__(self, num_envs: int = 4) -> None:
        super().__init__(num_envs)
        self._info["disc_obs"] = self._pos
        self._info["disc_obs_demo"] = self._target
        self.disc_fn: Callable[[torch.Tensor], torch.Tensor] | None = None

    def get_disc_obs_space(self) -> BoxSpace:
        return BoxSpace.unbounded(2)

    def get_disc_obs_demo(self) -> torch.Tensor:
        return self._target

    def fetch_disc_obs_demo(self, num_samples: int) -> torch.Tensor:
        raise AssertionError("ADD pairs each row with its own reference; it never fetches demos")

    def set_disc_reward_fn(self, fn: Callable[[torch.Tensor], torch.Tensor] | None, task_weight: float = 1.0,
                           disc_weight: float = 1.0) -> None:  # fmt: skip
        self.disc_fn = fn


def add_config(**overrides) -> ADDAgentConfig:
    cfg = ppo_config_dict(agent_name="ADD", steps_per_iter=8, iters_per_output=2, test_episodes=0)
    cfg["model"] = dict(cfg["model"], disc_net="fc_2layers_128units")
    cfg.update(
        disc_optimizer={"type": "SGD", "learning_rate": 2.5e-4, "weight_decay": 1e-4},
        disc_epochs=2, disc_batch_size=2, disc_buffer_size=100, disc_replay_samples=5, disc_logit_reg=0.01,
        disc_grad_penalty=2.0, disc_reward_scale=2.0, task_reward_weight=0.0, disc_reward_weight=1.0,
    )  # fmt: skip
    cfg.update(overrides)
    return ADDAgentConfig(**cfg)


# The discriminator set by hand: hidden 1 = x + C (C keeps every ReLU on its linear side), hidden 2 =
# 2·hidden 1, logit = A·hidden 2 + B, so D(x) = 2A·x + 2A·C + B = (1, -0.5)·x − 2 and ∇D = 2A everywhere.
A, C, B = torch.tensor([0.5, -0.25]), 10.0, -7.0


def hand_set_disc(agent: ADDAgent) -> None:
    layers, logits = agent._model._disc_layers, agent._model._disc_logits
    with torch.no_grad():
        for p in [*layers.parameters(), *logits.parameters()]:
            p.zero_()
        layers[0].weight[:2, :2] = torch.eye(2)
        layers[0].bias[:2] = C
        layers[2].weight[:2, :2] = 2.0 * torch.eye(2)
        logits.weight[0, :2] = A
        logits.bias.fill_(B)
        agent._disc_obs_norm._mean_abs.copy_(torch.tensor([2.0, 4.0]))


def toy_agent(**overrides) -> tuple[DiffToyEnv, ADDAgent]:
    env = DiffToyEnv()
    agent = build_agent_from_config(add_config(**overrides), env, "cpu")
    assert isinstance(agent, ADDAgent)
    hand_set_disc(agent)
    return env, agent


def softplus(x: float) -> float:
    return math.log1p(math.exp(x))


# ------------------------------------------------------------------ by hand on the toy env


def test_disc_input_is_the_normalised_difference_reference_minus_agent():
    env, agent = toy_agent()
    assert isinstance(agent._disc_obs_norm, DiffNormalizer)
    agent._exp_buffer.set_data("disc_obs", torch.tensor([[[1.0, 1.0]], [[0.0, 0.0]]]).repeat(4, 4, 1))
    agent._exp_buffer.set_data("disc_obs_demo", torch.tensor([[[3.0, 5.0]], [[2.0, -4.0]]]).repeat(4, 4, 1))
    diff = agent._disc_input_flat()
    assert diff.shape == (32, 2) and torch.equal(diff[:4], torch.tensor([[2.0, 4.0]]).expand(4, 2))
    # Normalised by mean |diff| = (2, 4): (1, 1) → D = 1 − 0.5 − 2 = −1.5; r = softplus(−1.5) · 2.
    rewards = agent._calc_disc_rewards(diff[:1])
    assert rewards.item() == pytest.approx(2 * softplus(-1.5), rel=1e-5)
    assert env.disc_fn is not None and env.disc_fn(diff[:1]).item() == pytest.approx(rewards.item())


def test_rewards_are_the_weighted_task_and_disc_rewards():
    _, agent = toy_agent(task_reward_weight=0.5, disc_reward_weight=3.0)
    agent._exp_buffer.set_data("disc_obs", torch.zeros(8, 4, 2))
    agent._exp_buffer.set_data("disc_obs_demo", torch.tensor([2.0, -4.0]).expand(8, 4, 2).clone())
    task_r = torch.rand(8, 4)
    agent._exp_buffer.set_data("reward", task_r)
    info = agent._compute_rewards()
    disc_r = 2 * softplus(1 + 0.5 - 2)  # normalised (1, −1)
    torch.testing.assert_close(agent._exp_buffer.get_data("reward"), 0.5 * task_r + 3.0 * disc_r)
    assert info["disc_reward_mean"] == pytest.approx(disc_r, rel=1e-5) and info["disc_reward_std"] < 1e-5


def test_each_loss_term_by_hand():
    _, agent = toy_agent()
    agent._disc_buffer.push({"disc_obs": torch.tensor([4.0, 0.0]).expand(50, 1, 2)})  # normalised (2, 0): D = 0
    batch = {
        "disc_obs": torch.tensor([[1.0, 1.0], [0.0, 0.0]]),
        "disc_obs_demo": torch.tensor([[3.0, 5.0], [2.0, -4.0]]),
    }
    info = agent._compute_disc_loss(batch)
    # Negatives: the batch's differences (2, 4), (2, −4) → normalised (1, 1), (1, −1) → D = −1.5, −0.5; two
    # replayed → D = 0, 0. Positive: the zero difference → D = −2.
    neg = [-1.5, -0.5, 0.0, 0.0]
    bce = 0.5 * (softplus(2.0) + sum(softplus(x) for x in neg) / 4)  # BCE(l, 1) = softplus(−l), BCE(l, 0) = softplus(l)
    logit_reg = 0.5**2 + 0.25**2  # Σ w² of the logit layer
    grad_penalty = 0.5 * (4 * logit_reg + 4 * logit_reg)  # ‖∇D‖² = ‖2A‖² at every negative and at 0
    assert info["disc_logit_loss"].item() == pytest.approx(logit_reg)
    assert info["disc_grad_penalty"].item() == pytest.approx(grad_penalty, rel=1e-6)
    assert info["disc_loss"].item() == pytest.approx(bce + 0.01 * logit_reg + 2.0 * grad_penalty, rel=1e-6)
    assert info["disc_pos_logit"].item() == pytest.approx(-2.0) and info["disc_neg_logit"].item() == pytest.approx(-0.5)
    assert info["disc_pos_acc"].item() == 0.0 and info["disc_neg_acc"].item() == 0.5  # D(0) > 0 / D(Δ) < 0
    # The BCE itself as torch computes it, in case the hand formulas above were wrong together.
    torch_bce = 0.5 * (
        F.binary_cross_entropy_with_logits(torch.tensor([-2.0]), torch.ones(1))
        + F.binary_cross_entropy_with_logits(torch.tensor(neg), torch.zeros(4))
    )
    assert torch_bce.item() == pytest.approx(bce, rel=1e-6)
    # The logit regulariser is always added, whatever its weight.
    _, no_reg = toy_agent(disc_logit_reg=0.0)
    no_reg._disc_buffer.push({"disc_obs": torch.tensor([4.0, 0.0]).expand(50, 1, 2)})
    info = no_reg._compute_disc_loss(batch)
    assert info["disc_loss"].item() == pytest.approx(bce + 2.0 * grad_penalty, rel=1e-6)
    assert info["disc_logit_loss"].item() == pytest.approx(logit_reg)


def test_the_gradient_penalty_is_optimised():
    """GP = 4‖A‖² with the hand-set net, so raising its weight by 1 adds exactly 8A to ∂loss/∂A."""
    grads = []
    for weight in (2.0, 3.0):
        _, agent = toy_agent(disc_grad_penalty=weight)
        agent._disc_buffer.push({"disc_obs": torch.zeros(10, 1, 2)})
        agent._compute_disc_loss({"disc_obs": torch.zeros(3, 2), "disc_obs_demo": torch.ones(3, 2)})[
            "disc_loss"
        ].backward()
        grads.append(agent._model._disc_logits.weight.grad[0, :2].clone())
    torch.testing.assert_close(grads[1] - grads[0], 8 * A)


def test_disc_weight_decay_goes_through_the_disc_optimizer():
    _, agent = toy_agent()
    params = list(agent._model.get_disc_params())
    before = [p.detach().clone() for p in params]
    actor_before = [p.detach().clone() for p in agent._model.get_actor_params()]
    agent._disc_optimizer.step(sum(0.0 * p.sum() for p in params))  # zero loss gradient: only the decay acts
    for p, b in zip(params, before, strict=True):  # SGD: p ← p − lr·(∇ + wd·p)
        torch.testing.assert_close(p.detach(), b * (1 - 2.5e-4 * 1e-4), rtol=0, atol=1e-12)
    assert all(torch.equal(p, b) for p, b in zip(agent._model.get_actor_params(), actor_before, strict=True))
    assert any((b != 0).any() for b in before), "the decay was observable"


def test_post_step_records_both_sides_and_the_normaliser_the_differences():
    env, agent = toy_agent()
    obs, info = env.reset()
    agent._record_data_post_step(obs, torch.zeros(4), torch.zeros(4, dtype=torch.long), info)
    torch.testing.assert_close(agent._exp_buffer.get_data("disc_obs")[0], env._pos)
    torch.testing.assert_close(agent._exp_buffer.get_data("disc_obs_demo")[0], env._target)
    agent._disc_obs_norm.update()
    torch.testing.assert_close(agent._disc_obs_norm.get_mean_abs(), (env._target - env._pos).abs().mean(0))


def test_add_needs_the_reference_disc_obs():
    with pytest.raises(MimicKitError, match="agent ADD needs an env with reference disc obs"):
        build_agent_from_config(add_config(), TargetReachEnv(num_envs=2), "cpu")
    env_cfg, engine_cfg = load_env_configs(AMP_ENV, ENGINE)
    from mimickit.envs.amp_env import AMPEnv

    with pytest.raises(MimicKitError, match="env_name add"):
        build_agent_from_config(add_config(), AMPEnv(env_cfg, engine_cfg, 2), "cpu")


def test_shipped_add_agent_yaml_has_the_reference_values():
    cfg = load_agent_config(PROJECT_DATA_DIR / "agents/add_humanoid_agent.yaml")
    assert isinstance(cfg, ADDAgentConfig) and cfg.model.disc_net == "fc_2layers_1024units"
    assert (cfg.model.actor_net, cfg.model.critic_net, cfg.model.action_std) == (
        "fc_2layers_1024units", "fc_2layers_1024units", 0.05,
    )  # fmt: skip
    assert (cfg.disc_optimizer.type, cfg.disc_optimizer.learning_rate, cfg.disc_optimizer.weight_decay) == (
        "SGD", 2.5e-4, 1e-4,
    )  # fmt: skip
    assert (cfg.disc_epochs, cfg.disc_batch_size, cfg.disc_buffer_size, cfg.disc_replay_samples) == (2, 2, 200000, 1000)
    assert (cfg.disc_logit_reg, cfg.disc_grad_penalty, cfg.disc_reward_scale) == (0.01, 2.0, 2.0)
    assert (cfg.task_reward_weight, cfg.disc_reward_weight, cfg.steps_per_iter) == (0.0, 1.0, 32)


# ------------------------------------------------------------------ the agent on the ADD env


def make_humanoid_agent(num_envs: int = 4) -> tuple[ADDEnv, ADDAgent]:
    env_cfg, engine_cfg = load_env_configs(ADD_ENV, ENGINE)
    env = ADDEnv(env_cfg.model_copy(update={"motion_file": str(DEMO_CLIP)}), engine_cfg, num_envs)
    agent = build_agent_from_config(add_config(), env, "cpu")
    assert isinstance(agent, ADDAgent)
    return env, agent


def test_training_on_the_humanoid_logs_disc_metrics_and_saves_the_reference_keys(tmp_path):
    env, agent = make_humanoid_agent()
    assert env.reward_weights == {"task": 0.0, "disc": 1.0}
    agent.train_model(3 * 32, tmp_path)
    rows = [json.loads(line) for line in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    assert len(rows) == 3
    for row in rows:
        # The per-step style reward the env reports is the reward the agent trains on.
        assert row["reward_terms.disc"] == pytest.approx(row["disc_reward_mean"], rel=1e-4)
        assert row["reward_terms.task"] == 0.0 and row["train_return"] == 0.0
        assert 0.0 <= row["disc_pos_acc"] <= 1.0 and 0.0 <= row["disc_neg_acc"] <= 1.0
        assert row["tracking.body_pos_err"] > 0 and row["disc_logit_loss"] > 0
    # The normaliser's mean |Δ| is the rollouts' (all three recorded; first update from a count of 0).
    assert agent._disc_obs_norm.get_count() == 3 * 32
    state = torch.load(tmp_path / "model.pt", weights_only=True)
    assert {k for k in state if "disc" in k} == {
        "_disc_obs_norm._count", "_disc_obs_norm._mean_abs",
        "_model._disc_layers.0.weight", "_model._disc_layers.0.bias",
        "_model._disc_layers.2.weight", "_model._disc_layers.2.bias",
        "_model._disc_logits.weight", "_model._disc_logits.bias",
    }  # fmt: skip
    assert state["_model._disc_layers.0.weight"].shape == (128, 172)
    assert set(state[TRAIN_STATE_KEY]["optimizers"]) == {"actor", "critic", "disc"}

    fresh_env, fresh = make_humanoid_agent()
    fresh.load(tmp_path / "model.pt")
    torch.testing.assert_close(fresh._disc_obs_norm.get_mean_abs(), agent._disc_obs_norm.get_mean_abs())
    obs, _ = fresh_env.reset()
    _, _, _, info = fresh_env.step(fresh.compute_action(obs))
    diff = info["disc_obs_demo"] - info["disc_obs"]
    torch.testing.assert_close(info["reward_terms"]["disc"], agent._calc_disc_rewards(diff))
