"""End-to-end agent runs on the toy env: learning, outputs, checkpoints, resume, stop."""

from __future__ import annotations

import json

import pytest
import torch

from mimickit.envs.base_env import EnvMode
from mimickit.learning.agent_builder import build_agent, build_agent_from_config
from mimickit.learning.agent_config import AWRAgentConfig, PPOAgentConfig
from mimickit.learning.base_agent import TRAIN_STATE_KEY, BaseAgent
from mimickit.learning.dummy_agent import DummyAgent
from mimickit.util.errors import MimicKitError
from tests.learning.conftest import awr_config_dict, ppo_config_dict
from tests.learning.toy_env import ACTION_LIMIT, TargetReachEnv

NUM_ENVS = 32
SAMPLES_PER_ITER = NUM_ENVS * 20


def make_ppo(num_envs: int = NUM_ENVS, extra_obs: int = 0, env: TargetReachEnv | None = None, **overrides) -> BaseAgent:
    env = env or TargetReachEnv(num_envs=num_envs, extra_obs=extra_obs)
    return build_agent_from_config(PPOAgentConfig(**ppo_config_dict(**overrides)), env, "cpu")


def read_metrics(path):
    return [json.loads(line) for line in path.read_text().splitlines()]


@pytest.mark.slow
def test_ppo_improves_and_writes_all_outputs(tmp_path):
    agent = make_ppo()
    before = agent.test_model(NUM_ENVS).mean_return
    summary = agent.train_model(16 * SAMPLES_PER_ITER, tmp_path, save_int_models=True, logger_type="tb")
    after = agent.test_model(NUM_ENVS).mean_return
    assert summary.iterations == 16 and summary.samples == 16 * SAMPLES_PER_ITER and not summary.stopped
    assert after > before + 6.0, (before, after)  # standing still ≈ 5, walking to the target ≈ 17

    rows = read_metrics(tmp_path / "metrics.jsonl")
    assert [r["iteration"] for r in rows] == list(range(16))
    expected = {"samples", "wall_time", "train_return", "train_episode_length", "test_return", "test_episode_length"}
    expected |= {"critic_loss", "actor_loss", "clip_frac", "reward_terms.reach", "tracking.pos_err", "target_dist"}
    assert expected <= set(rows[-1]), expected - set(rows[-1])
    assert [r["output"] for r in rows].count(True) == 4  # iterations 0, 5, 10 and the last
    assert 0.0 < rows[-1]["reward_terms.reach"] <= 1.0

    lines = (tmp_path / "log.txt").read_text().splitlines()
    header = lines[0].split()
    assert header[:11] == ["Iteration", "Wall_Time", "Samples", "Test_Return", "Test_Episode_Length", "Test_Episodes",
                           "Test_Fail_Frac", "Train_Return", "Train_Episode_Length", "Train_Episodes",
                           "Critic_Loss"]  # fmt: skip
    assert header[-3:] == ["Obs_Norm_Mean", "Obs_Norm_Std", "Exp_Prob"]
    assert [int(line.split()[0]) for line in lines[1:]] == [0, 5, 10, 15]
    assert all(len(line.split()) == len(header) for line in lines[1:])

    assert list(tmp_path.glob("events.out.tfevents.*"))
    assert (tmp_path / "model.pt").is_file()
    assert sorted(p.name for p in (tmp_path / "int_models").iterdir()) == [f"model_{i:010d}.pt" for i in (0, 5, 10, 15)]


class DriftEnv(TargetReachEnv):
    """The toy env with the point blown along +x at the action limit whatever the policy does: it leaves the
    arena within 15 steps, before the 20-step limit, so every episode ends in FAIL."""

    def step(self, action):
        return super().step(torch.full_like(action, ACTION_LIMIT))


@pytest.mark.parametrize(
    ("env", "fail_frac"), [(TargetReachEnv(NUM_ENVS, episode_steps=3), 0.0), (DriftEnv(NUM_ENVS), 1.0)]
)
def test_the_periodic_test_logs_the_share_of_episodes_that_failed(tmp_path, env, fail_frac):
    """A short mean test length need not be a fall (a clip that does not loop ends its episodes as a success):
    the test counts FAIL endings. Three steps cannot leave the arena; the drift always does."""
    agent = make_ppo(env=env)
    stats = agent.test_model(NUM_ENVS)
    assert stats.num_eps >= NUM_ENVS and stats.num_fail == fail_frac * stats.num_eps
    agent.train_model(SAMPLES_PER_ITER, tmp_path)
    (row,) = read_metrics(tmp_path / "metrics.jsonl")
    assert row["test_fail_frac"] == fail_frac and row["test_episodes"] >= NUM_ENVS


def test_checkpoint_keys_strict_load_and_same_test_actions(tmp_path):
    agent = make_ppo()
    agent.train_model(2 * SAMPLES_PER_ITER, tmp_path)
    state = torch.load(tmp_path / "model.pt", weights_only=True)
    model_keys = {k for k in state if k != TRAIN_STATE_KEY}
    assert model_keys == {
        "_obs_norm._count", "_obs_norm._mean", "_obs_norm._std", "_a_norm._count", "_a_norm._mean", "_a_norm._std",
        "_model._actor_layers.0.weight", "_model._actor_layers.0.bias",
        "_model._actor_layers.2.weight", "_model._actor_layers.2.bias",
        "_model._action_dist._mean_net.weight", "_model._action_dist._mean_net.bias",
        "_model._action_dist._logstd_net",
        "_model._critic_layers.0.weight", "_model._critic_layers.0.bias",
        "_model._critic_layers.2.weight", "_model._critic_layers.2.bias",
        "_model._critic_out.weight", "_model._critic_out.bias",
    }  # fmt: skip

    fresh = make_ppo()
    obs = torch.randn(NUM_ENVS, 6)
    assert not torch.equal(fresh.compute_action(obs), agent.compute_action(obs))
    fresh.load(tmp_path / "model.pt")
    assert torch.equal(fresh.compute_action(obs), agent.compute_action(obs))
    for (k, a), b in zip(agent.state_dict().items(), fresh.state_dict().values(), strict=True):
        assert torch.equal(a, b), k

    # a reference-style file (no training state) loads strictly too and starts a fresh curve
    agent.save(tmp_path / "ref.pt", include_train_state=False)
    assert TRAIN_STATE_KEY not in torch.load(tmp_path / "ref.pt", weights_only=True)
    other = make_ppo()
    other.load(tmp_path / "ref.pt")
    assert other.get_iteration() == 0 and torch.equal(other.compute_action(obs), agent.compute_action(obs))


def test_checkpoint_for_another_observation_size_is_refused(tmp_path):
    make_ppo().save(tmp_path / "model.pt")
    wider = make_ppo(extra_obs=3)
    with pytest.raises(MimicKitError) as e:
        wider.load(tmp_path / "model.pt")
    msg = str(e.value)
    assert str(tmp_path / "model.pt") in msg
    assert "observation size differs" in msg and "'_obs_norm._mean' has shape [6] in the checkpoint but [9] here" in msg
    with pytest.raises(MimicKitError, match="not a readable checkpoint"):
        (tmp_path / "junk.pt").write_bytes(b"not a zip")
        wider.load(tmp_path / "junk.pt")
    with pytest.raises(MimicKitError, match="model file not found"):
        wider.load(tmp_path / "missing.pt")


def test_resume_continues_iterations_samples_and_optimizer(tmp_path):
    first = make_ppo(iters_per_output=1)
    first.train_model(3 * SAMPLES_PER_ITER, tmp_path)
    resumed = make_ppo(iters_per_output=1)
    resumed.load(tmp_path / "model.pt")
    assert resumed.get_iteration() == 3 and resumed.get_sample_count() == 3 * SAMPLES_PER_ITER
    resumed.save(tmp_path / "resumed.pt")  # what it restored, as its own checkpoint writes it
    opt_a = torch.load(tmp_path / "model.pt", weights_only=True)[TRAIN_STATE_KEY]["optimizers"]["actor"]
    opt_b = torch.load(tmp_path / "resumed.pt", weights_only=True)[TRAIN_STATE_KEY]["optimizers"]["actor"]
    assert opt_a["steps"] == opt_b["steps"] > 0
    opt_a, opt_b = opt_a["optimizer"]["state"], opt_b["optimizer"]["state"]
    assert all(torch.equal(opt_a[i]["exp_avg"], opt_b[i]["exp_avg"]) for i in opt_a)

    summary = resumed.train_model(5 * SAMPLES_PER_ITER, tmp_path)
    assert summary.iterations == 5 and summary.samples == 5 * SAMPLES_PER_ITER
    all_rows = read_metrics(tmp_path / "metrics.jsonl")
    marker = all_rows[3]
    assert marker["event"] == "resume" and (marker["iteration"], marker["samples"]) == (3, 3 * SAMPLES_PER_ITER)
    assert marker["max_samples"] == 5 * SAMPLES_PER_ITER
    rows = [r for r in all_rows if "event" not in r]
    assert [r["iteration"] for r in rows] == [0, 1, 2, 3, 4]
    assert [r["samples"] for r in rows] == [SAMPLES_PER_ITER * (i + 1) for i in range(5)]
    assert rows[3]["wall_time"] >= rows[2]["wall_time"]
    lines = (tmp_path / "log.txt").read_text().splitlines()
    assert lines[0].startswith("Iteration") and [line.split()[0] for line in lines[1:]] == ["0", "1", "2", "3", "4"]


def test_request_stop_ends_training_and_saves(tmp_path):
    env = TargetReachEnv(num_envs=NUM_ENVS)
    agent = make_ppo(env=env, iters_per_output=100)
    real_step = env.step
    train_steps = 0

    def step_and_stop(action):
        nonlocal train_steps
        if env.get_mode() == EnvMode.TRAIN:
            train_steps += 1
            if train_steps == 2 * 20 + 5:  # in the middle of the third iteration
                agent.request_stop()
        return real_step(action)

    env.step = step_and_stop
    summary = agent.train_model(100 * SAMPLES_PER_ITER, tmp_path)
    assert summary.stopped and summary.iterations == 2 and summary.samples == 2 * SAMPLES_PER_ITER
    state = torch.load(tmp_path / "model.pt", weights_only=True)
    assert state[TRAIN_STATE_KEY]["iteration"] == 2 and state[TRAIN_STATE_KEY]["samples"] == 2 * SAMPLES_PER_ITER


@pytest.mark.slow
def test_awr_runs_and_improves(tmp_path):
    env = TargetReachEnv(num_envs=NUM_ENVS)
    agent = build_agent_from_config(AWRAgentConfig(**awr_config_dict()), env, "cpu")
    before = agent.test_model(NUM_ENVS).mean_return
    agent.train_model(12 * SAMPLES_PER_ITER, tmp_path)
    after = agent.test_model(NUM_ENVS).mean_return
    assert after > before + 4.0, (before, after)
    row = read_metrics(tmp_path / "metrics.jsonl")[-1]
    assert {"a_weight_mean", "a_weight_min", "a_weight_max", "actor_loss", "critic_loss"} <= set(row)
    assert row["a_weight_max"] <= 20.0


def test_no_agent_file_gives_the_dummy_agent_with_zero_actions():
    env = TargetReachEnv(num_envs=4)
    agent = build_agent(None, env, "cpu", verbose=False)
    assert isinstance(agent, DummyAgent) and agent.get_num_params() == 0
    assert torch.equal(agent.compute_action(torch.randn(4, 6)), torch.zeros(4, 2))
    stats = agent.test_model(4)
    assert stats.num_eps == 4 and stats.mean_ep_len == 20.0
    assert stats.to_dict() == {"mean_return": stats.mean_return, "mean_episode_length": 20.0, "episodes": 4}
    assert agent.test_model(0).num_eps == 0


@pytest.mark.parametrize(
    ("corrupt", "reason"),
    [("obs", "observation is nan"), ("reward", "reward is inf"), ("none", None)],
    ids=["nan-observation", "inf-reward", "finite"],
)
def test_divergence_guard_names_the_first_non_finite_quantity(tmp_path, corrupt, reason):
    """One env's observation (or reward) of the third iteration turns non-finite: training stops in that
    iteration, names it, keeps its metrics row and leaves model.pt with the finite weights it started from."""
    env = TargetReachEnv(num_envs=NUM_ENVS)
    agent = make_ppo(env=env, iters_per_output=100)
    real_step = env.step
    train_steps = 0

    def step(action):
        nonlocal train_steps
        obs, rew, done, info = real_step(action)
        if env.get_mode() == EnvMode.TRAIN:
            train_steps += 1
            if train_steps == 2 * 20 + 7 and corrupt == "obs":
                obs = obs.clone()
                obs[3, 1] = float("nan")
            if train_steps == 2 * 20 + 7 and corrupt == "reward":
                rew = rew.clone()
                rew[5] = float("inf")
        return obs, rew, done, info

    env.step = step
    summary = agent.train_model(4 * SAMPLES_PER_ITER, tmp_path)
    rows = read_metrics(tmp_path / "metrics.jsonl")
    state = torch.load(tmp_path / "model.pt", weights_only=True)
    weights = [v for k, v in state.items() if k != TRAIN_STATE_KEY and v.is_floating_point()]
    assert all(bool(torch.isfinite(w).all()) for w in weights)
    if reason is None:
        assert not summary.diverged and summary.iterations == 4 and len(rows) == 4
        return
    assert summary.diverged == f"diverged at iteration 2: {reason}" and not summary.stopped
    assert (summary.iterations, summary.samples) == (2, 2 * SAMPLES_PER_ITER)
    assert [r["iteration"] for r in rows] == [0, 1, 2]
    assert state[TRAIN_STATE_KEY]["iteration"] == 2 and state[TRAIN_STATE_KEY]["samples"] == 2 * SAMPLES_PER_ITER
    assert (tmp_path / "log.txt").read_text().splitlines()[-1] == f"# {summary.diverged}"
    own = agent.state_dict()  # rolled back to the start of iteration 2: what model.pt holds
    assert all(torch.equal(own[k], v) for k, v in state.items() if k != TRAIN_STATE_KEY)
