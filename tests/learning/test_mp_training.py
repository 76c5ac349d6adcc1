"""Two CPU processes training one PPO agent over torch.distributed (gloo)."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest
import torch
import torch.multiprocessing as mp

pytestmark = pytest.mark.integration

NUM_ENVS = 8
STEPS = 20


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def _train_rank(rank: int, world: int, port: int, out_dir: str) -> None:
    from mimickit.learning import mp_util
    from mimickit.learning.agent_builder import build_agent_from_config
    from mimickit.learning.agent_config import PPOAgentConfig
    from tests.learning.conftest import ppo_config_dict
    from tests.learning.toy_env import TargetReachEnv

    torch.set_num_threads(1)
    mp_util.init(rank, world, "cpu", port)
    torch.manual_seed(1 + 41 * rank)  # different rollouts per rank; parameters must still agree
    try:
        env = TargetReachEnv(num_envs=NUM_ENVS)
        cfg = PPOAgentConfig(**ppo_config_dict(iters_per_output=1, test_episodes=world * NUM_ENVS))
        agent = build_agent_from_config(cfg, env, "cpu")
        summary = agent.train_model(2 * world * NUM_ENVS * STEPS, out_dir)
        params = torch.nn.utils.parameters_to_vector(agent.parameters()).detach()
        torch.save(
            {"params": params, "obs_mean": agent.state_dict()["_obs_norm._mean"], "samples": summary.samples,
             "iterations": summary.iterations},
            Path(out_dir) / f"rank{rank}.pt",
        )  # fmt: skip
    finally:
        mp_util.shutdown()


@pytest.mark.slow  # two interpreters importing torch: ~8 s on the shared 2-core machine
def test_two_process_training_keeps_parameters_identical(tmp_path):
    world = 2
    mp.spawn(_train_rank, args=(world, _free_port(), str(tmp_path)), nprocs=world, join=True)
    r0 = torch.load(tmp_path / "rank0.pt", weights_only=True)
    r1 = torch.load(tmp_path / "rank1.pt", weights_only=True)
    assert r0["iterations"] == r1["iterations"] == 2
    assert r0["samples"] == r1["samples"] == 2 * world * NUM_ENVS * STEPS  # global count
    assert torch.equal(r0["params"], r1["params"])
    assert torch.equal(r0["obs_mean"], r1["obs_mean"])  # normaliser statistics all-reduced
    assert (tmp_path / "model.pt").is_file() and (tmp_path / "metrics.jsonl").read_text().count("\n") == 2
