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
from mimickit.envs.env_builder import load_env_configs
from mimickit.learning.add_agent import ADDAgent, compute_disc_loss, disc_input
from mimickit.learning.agent_builder import build_agent_from_config, load_agent_config
from mimickit.learning.agent_config import ADDAgentConfig
from mimickit.learning.amp_agent import calc_disc_rewards, style_rewards
from mimickit.learning.amp_model import AMPModel
from mimickit.learning.base_agent import TRAIN_STATE_KEY
from mimickit.learning.mp_optimizer import MPOptimizer
from mimickit.learning.normalizer import DiffNormalizer
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA_DIR
from tests.learning.conftest import disc_config_dict, first_step_info
from tests.learning.toy_env import TargetReachEnv

ENGINE = PROJECT_DATA_DIR / "engines/mujoco_engine.yaml"
ADD_ENV = PROJECT_DATA_DIR / "envs/add_humanoid_env.yaml"
AMP_ENV = PROJECT_DATA_DIR / "envs/amp_humanoid_env.yaml"
DEMO_CLIP = PROJECT_DATA_DIR / "motions/humanoid_demo_squat.pkl"


class DiffToyEnv(TargetReachEnv):
    """The toy env with ADD's interface: the agent's disc obs is the point, the reference's the target.
    It keeps each step's difference target − point (`diffs`), as the agent sees it right after the step."""

    def __init__(self, num_envs: int = 4) -> None:
        super().__init__(num_envs)
        self._info["disc_obs"] = self._pos
        self._info["disc_obs_demo"] = self._target
        self.disc_fn: Callable[[torch.Tensor], torch.Tensor] | None = None
        self.diffs: list[torch.Tensor] = []

    def get_disc_obs_space(self) -> BoxSpace:
        return BoxSpace.unbounded(2)

    def get_disc_obs_demo(self) -> torch.Tensor:
        return self._target

    def fetch_disc_obs_demo(self, num_samples: int) -> torch.Tensor:
        raise AssertionError("ADD pairs each row with its own reference; it never fetches demos")

    def set_disc_reward_fn(self, fn: Callable[[torch.Tensor], torch.Tensor] | None, task_weight: float = 1.0,
                           disc_weight: float = 1.0) -> None:  # fmt: skip
        self.disc_fn = fn

    def step(self, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, dict]:
        out = super().step(action)
        self.diffs.append((self._target - self._pos).clone())
        return out


def add_config(**overrides) -> ADDAgentConfig:
    cfg = disc_config_dict("ADD", disc_grad_penalty=2.0)
    cfg.update(overrides)
    return ADDAgentConfig(**cfg)


# The discriminator set by hand: hidden 1 = x + C (C keeps every ReLU on its linear side), hidden 2 =
# 2·hidden 1, logit = A·hidden 2 + B, so D(x) = 2A·x + 2A·C + B = (1, -0.5)·x − 2 and ∇D = 2A everywhere.
# The normaliser's mean |Δ| is (2, 4).
A, C, B = torch.tensor([0.5, -0.25]), 10.0, -7.0
MEAN_ABS = torch.tensor([2.0, 4.0])


def hand_set_disc(module: torch.nn.Module) -> None:
    """Set the discriminator and normaliser above through the checkpoint keys (an agent's, or those of
    `disc_parts`), so the numbers below are the ones a saved model would hold."""
    state = {k: v.clone() for k, v in module.state_dict().items()}
    for k, v in state.items():
        if k.startswith("_model._disc"):
            v.zero_()
    state["_model._disc_layers.0.weight"][:2, :2] = torch.eye(2)
    state["_model._disc_layers.0.bias"][:2] = C
    state["_model._disc_layers.2.weight"][:2, :2] = 2.0 * torch.eye(2)
    state["_model._disc_logits.weight"][0, :2] = A
    state["_model._disc_logits.bias"].fill_(B)
    state["_disc_obs_norm._mean_abs"] = MEAN_ABS.clone()
    module.load_state_dict(state)


def disc_parts() -> tuple[AMPModel, DiffNormalizer]:
    """ADD's networks (for the toy env's sizes) and normaliser, set by hand, without an agent."""
    model, norm = AMPModel(add_config().model, 6, 2, 2), DiffNormalizer((2,))
    hand_set_disc(torch.nn.ModuleDict({"_model": model, "_disc_obs_norm": norm}))
    return model, norm


def toy_agent(**overrides) -> tuple[DiffToyEnv, ADDAgent]:
    env = DiffToyEnv()
    agent = build_agent_from_config(add_config(**overrides), env, "cpu")
    assert isinstance(agent, ADDAgent)
    hand_set_disc(agent)
    return env, agent


def softplus(x: float) -> float:
    return math.log1p(math.exp(x))


def hand_disc_reward(diff: torch.Tensor) -> torch.Tensor:
    """r = −log(1 − sigmoid(D)) · 2 = 2 · softplus(D) of the hand-set D on normalised differences [B, 2]."""
    logit = (diff / MEAN_ABS) @ torch.tensor([1.0, -0.5]) - 2.0
    return 2.0 * F.softplus(logit)


# ------------------------------------------------------------------ by hand on the toy env


def test_disc_input_is_the_normalised_difference_reference_minus_agent():
    diff = disc_input(torch.tensor([[1.0, 1.0], [0.0, 0.0]]), torch.tensor([[3.0, 5.0], [2.0, -4.0]]))
    assert torch.equal(diff, torch.tensor([[2.0, 4.0], [2.0, -4.0]]))
    # Normalised by mean |diff| = (2, 4): (1, 1) → D = 1 − 0.5 − 2 = −1.5; r = softplus(−1.5) · 2.
    model, norm = disc_parts()
    rewards = calc_disc_rewards(model, norm, diff, 2.0)
    assert rewards[0].item() == pytest.approx(2 * softplus(-1.5), rel=1e-5)
    assert rewards[1].item() == pytest.approx(2 * softplus(1 + 0.5 - 2), rel=1e-5)  # normalised (1, −1)
    # In chunks of one row, the same; and the agent hands the env this very reward of its discriminator.
    torch.testing.assert_close(calc_disc_rewards(model, norm, diff, 2.0, eval_batch_size=1), rewards)
    env, _ = toy_agent()
    assert env.disc_fn is not None
    torch.testing.assert_close(env.disc_fn(diff), rewards)


def test_rewards_are_the_weighted_task_and_disc_rewards():
    task_r, disc_r = torch.rand(8, 4), torch.full((8, 4), 0.75)
    reward, info = style_rewards(task_r, disc_r, 0.5, 3.0)
    torch.testing.assert_close(reward, 0.5 * task_r + 3.0 * 0.75)
    assert info == {"disc_reward_mean": pytest.approx(0.75), "disc_reward_std": pytest.approx(0.0, abs=1e-6)}


def test_an_iteration_normalises_and_rewards_the_differences_of_its_rollout():
    """The rollout's rewards come from the pre-update discriminator and normaliser on target − point
    right after each step; then the normaliser takes the rollout's mean |Δ| (its count was 0)."""
    env, agent = toy_agent(task_reward_weight=0.5, disc_reward_weight=3.0)
    agent.start_training()
    step = agent.train_iteration()
    assert step is not None and len(env.diffs) == 8
    diffs = torch.cat(env.diffs)
    expected = hand_disc_reward(diffs)
    assert step.info["disc_reward_mean"] == pytest.approx(expected.mean().item(), rel=1e-5)
    assert step.info["disc_reward_std"] == pytest.approx(expected.std().item(), rel=1e-4)
    state = agent.state_dict()
    torch.testing.assert_close(state["_disc_obs_norm._mean_abs"], diffs.abs().mean(0))
    assert state["_disc_obs_norm._count"].item() == 32


def test_each_loss_term_by_hand():
    model, norm = disc_parts()
    # Negatives: the batch's differences (2, 4), (2, −4) → normalised (1, 1), (1, −1) → D = −1.5, −0.5; two
    # replayed (4, 0) → normalised (2, 0) → D = 0, 0. Positive: the zero difference → D = −2.
    diffs = torch.tensor([[2.0, 4.0], [2.0, -4.0], [4.0, 0.0], [4.0, 0.0]])
    info = compute_disc_loss(model, norm, diffs, logit_reg=0.01, grad_penalty=2.0)
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
    # The logit regulariser is always logged, whatever its weight.
    info = compute_disc_loss(model, norm, diffs, logit_reg=0.0, grad_penalty=2.0)
    assert info["disc_loss"].item() == pytest.approx(bce + 2.0 * grad_penalty, rel=1e-6)
    assert info["disc_logit_loss"].item() == pytest.approx(logit_reg)


def test_the_gradient_penalty_is_optimised():
    """GP = 4‖A‖² with the hand-set net, so raising its weight by 1 adds exactly 8A to ∂loss/∂A."""
    grads = []
    for weight in (2.0, 3.0):
        model, norm = disc_parts()
        diffs = torch.cat([torch.ones(3, 2), torch.zeros(3, 2)])  # the batch's, then the replayed
        compute_disc_loss(model, norm, diffs, logit_reg=0.01, grad_penalty=weight)["disc_loss"].backward()
        grads.append(dict(model.named_parameters())["_disc_logits.weight"].grad[0, :2].clone())
    torch.testing.assert_close(grads[1] - grads[0], 8 * A)


def test_disc_weight_decay_goes_through_the_disc_optimizer(tmp_path):
    cfg = add_config()
    model, _ = disc_parts()
    params = list(model.get_disc_params())
    before = [p.detach().clone() for p in params]
    actor_before = [p.detach().clone() for p in model.get_actor_params()]
    MPOptimizer(cfg.disc_optimizer, params).step(sum(0.0 * p.sum() for p in params))  # zero gradient: only decay
    for p, b in zip(params, before, strict=True):  # SGD: p ← p − lr·(∇ + wd·p)
        torch.testing.assert_close(p.detach(), b * (1 - 2.5e-4 * 1e-4), rtol=0, atol=1e-12)
    assert all(torch.equal(p, b) for p, b in zip(model.get_actor_params(), actor_before, strict=True))
    assert any((b != 0).any() for b in before), "the decay was observable"
    # The agent's disc optimiser is that one: the discriminator's parameters, with the decay (its checkpoint).
    _, agent = toy_agent()
    agent.save(tmp_path / "model.pt")
    (group,) = torch.load(tmp_path / "model.pt", weights_only=True)[TRAIN_STATE_KEY]["optimizers"]["disc"]["optimizer"][
        "param_groups"
    ]
    assert (group["lr"], group["weight_decay"], len(group["params"])) == (2.5e-4, 1e-4, len(params))


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
    state = torch.load(tmp_path / "model.pt", weights_only=True)
    # The normaliser's mean |Δ| is the rollouts' (all three recorded; first update from a count of 0).
    assert state["_disc_obs_norm._count"].item() == 3 * 32
    assert {k for k in state if "disc" in k} == {
        "_disc_obs_norm._count", "_disc_obs_norm._mean_abs",
        "_model._disc_layers.0.weight", "_model._disc_layers.0.bias",
        "_model._disc_layers.2.weight", "_model._disc_layers.2.bias",
        "_model._disc_logits.weight", "_model._disc_logits.bias",
    }  # fmt: skip
    assert state["_model._disc_layers.0.weight"].shape == (128, 172)
    assert set(state[TRAIN_STATE_KEY]["optimizers"]) == {"actor", "critic", "disc"}

    # Loaded, the agent scores a step as the one that saved it (the env's style reward is its disc's).
    fresh_env, fresh = make_humanoid_agent()
    fresh.load(tmp_path / "model.pt")
    torch.testing.assert_close(fresh.state_dict()["_disc_obs_norm._mean_abs"], state["_disc_obs_norm._mean_abs"])
    reward = first_step_info(fresh_env, fresh)["reward_terms"]["disc"]
    torch.testing.assert_close(reward, first_step_info(env, agent)["reward_terms"]["disc"])
    assert bool((reward > 0).all())
