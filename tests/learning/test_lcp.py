"""LCP (Lipschitz-constrained policies, the reference's LCPAgent): PPO whose actor loss adds `lcp_weight` ×
the mean over the minibatch of ‖∇ₓ log π(a|x)‖². The penalty is checked against central finite differences
of the log-probability (float64, no autograd in the check), the agent through training runs on the toy env."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
import torch

from mimickit.learning import rl_util
from mimickit.learning.agent_builder import AGENTS, build_agent_from_config, load_agent_config
from mimickit.learning.agent_config import LCPAgentConfig, PPOAgentConfig
from mimickit.learning.distributions import GaussianDiag
from mimickit.util.paths import PROJECT_DATA_DIR, PROJECT_ROOT
from tests.learning.conftest import ppo_config_dict
from tests.learning.toy_env import TargetReachEnv
from tests.util.config_errors import load_error

NUM_ENVS = 16


class TanhActor(torch.nn.Module):
    """A small nonlinear Gaussian actor (its gradient is not constant in x)."""

    def __init__(self, obs: int, act: int) -> None:
        super().__init__()
        g = torch.Generator().manual_seed(0)
        self.w1 = torch.nn.Parameter(torch.randn(obs, 8, generator=g, dtype=torch.float64))
        self.w2 = torch.nn.Parameter(torch.randn(8, act, generator=g, dtype=torch.float64))
        self.logstd = torch.nn.Parameter(torch.full((act,), -0.7, dtype=torch.float64))

    def forward(self, x: torch.Tensor) -> GaussianDiag:
        return GaussianDiag(torch.tanh(x @ self.w1) @ self.w2, self.logstd)


def finite_difference_penalty(actor: TanhActor, x: torch.Tensor, a: torch.Tensor, h: float = 1e-6) -> float:
    """mean over rows of Σ_i ((log π(a|x+h e_i) − log π(a|x−h e_i)) / 2h)²."""
    with torch.no_grad():
        grads = torch.zeros_like(x)
        for i in range(x.shape[1]):
            e = torch.zeros_like(x)
            e[:, i] = h
            grads[:, i] = (actor(x + e).log_prob(a) - actor(x - e).log_prob(a)) / (2 * h)
    return float(grads.square().sum(dim=1).mean())


def test_the_penalty_is_the_squared_gradient_norm_of_the_log_probability():
    actor = TanhActor(5, 3)
    g = torch.Generator().manual_seed(1)
    x = torch.randn(7, 5, generator=g, dtype=torch.float64)
    a = torch.randn(7, 3, generator=g, dtype=torch.float64)
    penalty = rl_util.lcp_penalty(actor, x, a)
    assert penalty.item() == pytest.approx(finite_difference_penalty(actor, x, a), rel=1e-7)
    # The actor's parameters get its gradient (create_graph): the optimiser steps through the penalty.
    penalty.backward()
    assert actor.w1.grad is not None and float(actor.w1.grad.abs().sum()) > 0


def test_the_penalty_of_a_linear_actor_is_its_closed_form():
    """μ = W x, σ fixed: ∇ₓ log π(a|x) = Wᵀ (a − W x) / σ² per row."""
    actor = TanhActor(4, 2)
    w = torch.randn(2, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    linear = lambda x: GaussianDiag(x @ w.T, actor.logstd)  # noqa: E731
    x = torch.randn(6, 4, dtype=torch.float64)
    a = torch.randn(6, 2, dtype=torch.float64)
    var = torch.exp(2 * actor.logstd.detach())
    grad = ((a - x @ w.T) / var) @ w
    assert float(rl_util.lcp_penalty(linear, x, a)) == pytest.approx(float(grad.square().sum(1).mean()), rel=1e-12)


def test_the_shipped_lcp_yaml_is_the_g1_ppo_one_plus_its_weight():
    lcp = load_agent_config(PROJECT_DATA_DIR / "agents" / "lcp_g1_agent.yaml")
    ppo = load_agent_config(PROJECT_DATA_DIR / "agents" / "deepmimic_g1_ppo_agent.yaml")
    assert isinstance(lcp, LCPAgentConfig) and lcp.lcp_weight == 0.002  # the reference's lcp_g1_agent.yaml
    assert lcp.model_dump(exclude={"agent_name", "lcp_weight"}) == ppo.model_dump(exclude={"agent_name", "lcp_weight"})
    assert AGENTS.resolve("LCP") is AGENTS.resolve("PPO")


@pytest.mark.parametrize(
    ("extra", "needle"), [("", "missing required key 'lcp_weight'"), ("lcp_weight: -1\n", "lcp_weight")]
)
def test_an_lcp_yaml_without_a_valid_weight_is_one_line(tmp_path, extra, needle):
    text = (PROJECT_DATA_DIR / "agents" / "lcp_g1_agent.yaml").read_text().replace("lcp_weight: 0.002\n", extra)
    f, msg = load_error(tmp_path, text, load_agent_config, "agent.yaml")
    assert str(f) in msg and needle in msg and "\n" not in msg


def train_rows(tmp_path, config) -> list[dict]:
    torch.manual_seed(0)
    agent = build_agent_from_config(config, TargetReachEnv(num_envs=NUM_ENVS), "cpu")
    agent.train_model(2 * NUM_ENVS * 20, tmp_path)
    return [json.loads(line) for line in (tmp_path / "metrics.jsonl").read_text().splitlines()]


def test_lcp_logs_its_loss_and_any_actor_critic_agent_takes_the_weight(tmp_path):
    """With the weight, each iteration logs lcp_loss; PPO without it logs none. The agent is PPO's class:
    the same seed gives the same first rollout, so the first iteration's returns are equal."""
    base = ppo_config_dict()
    rows_lcp = train_rows(tmp_path / "lcp", LCPAgentConfig(**{**base, "agent_name": "LCP", "lcp_weight": 0.5}))
    rows_ppo = train_rows(tmp_path / "ppo", PPOAgentConfig(**base))
    assert all(r["lcp_loss"] > 0 for r in rows_lcp) and not any("lcp_loss" in r for r in rows_ppo)
    assert rows_lcp[0]["train_return"] == rows_ppo[0]["train_return"]
    # Any actor-critic agent takes the weight: PPO with lcp_weight logs it too.
    rows_ppo_lcp = train_rows(tmp_path / "ppo_lcp", PPOAgentConfig(**{**base, "lcp_weight": 0.5}))
    assert rows_ppo_lcp[0]["lcp_loss"] == pytest.approx(rows_lcp[0]["lcp_loss"])


@pytest.mark.integration
def test_the_lcp_g1_arg_file_trains_on_mujoco(tmp_path, test_data):
    """`args/lcp_g1_ppo_args.txt` (MimicKit's lcp_g1_ppo_args.txt): the G1 on MuJoCo, one iteration of 2 envs."""
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "mimickit.cli", "train", "--arg_file", "args/lcp_g1_ppo_args.txt",
           "--data_dir", str(test_data), "--num_envs", "2", "--max_samples", "64", "--out_dir", str(out),
           "--rand_seed", "0"]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=PROJECT_ROOT)
    assert done.returncode == 0, done.stderr[-2000:]
    rows = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert rows[-1]["samples"] == 64 and rows[-1]["lcp_loss"] > 0
    assert "LCP" in (out / "agent_config.yaml").read_text().split("agent_name:")[1].splitlines()[0]
