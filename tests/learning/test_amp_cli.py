"""`mimickit train` / `mimickit test` with the shipped AMP arg file, in fresh processes: the real
humanoid AMP env (MuJoCo) and the reference agent yaml, three iterations of 4 envs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from mimickit.util.paths import PROJECT_ROOT
from tests.test_cli_train import metrics, mimickit

ARG_FILE = PROJECT_ROOT / "args" / "amp_humanoid_args.txt"
DISC_COLUMNS = [
    "Disc_Loss", "Disc_Grad_Penalty", "Disc_Agent_Acc", "Disc_Demo_Acc", "Disc_Agent_Logit", "Disc_Demo_Logit",
    "Disc_Logit_Loss",
]  # fmt: skip


def test_amp_train_writes_disc_metrics_and_the_checkpoint_tests_in_a_fresh_process(tmp_path: Path) -> None:
    out = tmp_path / "run"
    r = mimickit(
        "train", "--arg_file", str(ARG_FILE), "--num_envs", "4", "--max_samples", "384", "--out_dir", str(out),
        "--rand_seed", "0",
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    for name in ("log.txt", "metrics.jsonl", "model.pt", "env_config.yaml", "agent_config.yaml"):
        assert (out / name).is_file(), name

    header = (out / "log.txt").read_text().splitlines()[0].split()
    # The reference's columns: disc terms after the actor's, disc reward after the advantages.
    i = header.index("Action_Bound_Loss")
    assert header[i + 1 : i + 8] == DISC_COLUMNS
    assert header[i + 8 : i + 12] == ["Adv_Mean", "Adv_Std", "Disc_Reward_Mean", "Disc_Reward_Std"]

    rows = metrics(out)
    assert [m["samples"] for m in rows] == [128, 256, 384]
    for row in rows:
        for key in [c.lower() for c in DISC_COLUMNS] + ["disc_reward_mean", "disc_reward_std"]:
            assert key in row and row[key] is not None, key
        assert 0.0 <= row["disc_agent_acc"] <= 1.0 and 0.0 <= row["disc_demo_acc"] <= 1.0
        # The per-step style reward the env reports is the reward the agent trains on.
        assert row["reward_terms.disc"] == pytest.approx(row["disc_reward_mean"], rel=1e-4)
        assert row["reward_terms.task"] == 0.0
    assert rows[-1]["disc_agent_logit"] < rows[-1]["disc_demo_logit"], "the discriminator tells the clip apart"

    state = torch.load(out / "model.pt", weights_only=True)
    assert state["_model._disc_layers.0.weight"].shape == (1024, 1420)
    assert state["_disc_obs_norm._mean"].shape == (1420,)

    r = mimickit(
        "test", "--arg_file", str(ARG_FILE), "--num_envs", "2", "--model_file", str(out / "model.pt"),
        "--test_episodes", "2", "--json",
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    result = json.loads(r.stdout.strip().splitlines()[-1])
    assert result["episodes"] >= 2 and 0 < result["mean_episode_length"] <= 300
    assert result["mean_return"] == 0.0, "AMP envs have no task reward (the reference logs 0 too)"
