"""`mimickit train` / `mimickit test` with the shipped ADD arg file, in fresh processes: the humanoid ADD
env (MuJoCo) on MimicKit's walk clip (`--data_dir`, reference data) and the reference agent yaml,
three iterations of 4 envs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from mimickit.util.paths import PROJECT_ROOT
from tests.test_cli_train import metrics, mimickit

ARG_FILE = PROJECT_ROOT / "args" / "add_humanoid_args.txt"
DISC_COLUMNS = [
    "Disc_Loss", "Disc_Grad_Penalty", "Disc_Logit_Loss", "Disc_Pos_Acc", "Disc_Neg_Acc", "Disc_Pos_Logit",
    "Disc_Neg_Logit",
]  # fmt: skip
TRACKING = ["root_pos_err", "root_rot_err", "body_pos_err", "body_rot_err", "dof_vel_err", "root_vel_err",
            "root_ang_vel_err"]  # fmt: skip


def test_add_train_writes_outputs_and_the_checkpoint_tests_in_a_fresh_process(tmp_path: Path, test_data: Path) -> None:
    out = tmp_path / "run"
    common = ["--arg_file", str(ARG_FILE), "--data_dir", str(test_data)]
    r = mimickit("train", *common, "--num_envs", "4", "--max_samples", "384", "--out_dir", str(out), "--rand_seed", "0")
    assert r.returncode == 0, r.stderr[-3000:]
    for name in ("log.txt", "metrics.jsonl", "model.pt", "env_config.yaml", "agent_config.yaml"):
        assert (out / name).is_file(), name
    assert "humanoid_walk.pkl" in (out / "env_config.yaml").read_text()

    header = (out / "log.txt").read_text().splitlines()[0].split()
    i = header.index("Action_Bound_Loss")  # the reference's order: disc terms after the actor's
    assert header[i + 1 : i + 8] == DISC_COLUMNS
    assert header[i + 8 : i + 12] == ["Adv_Mean", "Adv_Std", "Disc_Reward_Mean", "Disc_Reward_Std"]
    assert [c.title() for c in TRACKING] == header[i + 12 : i + 19], "log_tracking_error: the test-mode means"

    rows = metrics(out)
    assert [m["samples"] for m in rows] == [128, 256, 384]
    for row in rows:
        for key in [c.lower() for c in DISC_COLUMNS] + ["disc_reward_mean", "disc_reward_std"]:
            assert key in row and row[key] is not None, key
        assert 0.0 <= row["disc_pos_acc"] <= 1.0 and 0.0 <= row["disc_neg_acc"] <= 1.0
        assert row["reward_terms.disc"] == pytest.approx(row["disc_reward_mean"], rel=1e-4)
        assert row["reward_terms.task"] == 0.0
        assert all(row[f"tracking.{k}"] >= 0.0 for k in TRACKING)
    # Any drift from the clip is a negative: the discriminator ranks the zero difference above them.
    assert rows[-1]["disc_neg_logit"] < rows[-1]["disc_pos_logit"]

    state = torch.load(out / "model.pt", weights_only=True)
    assert state["_model._disc_layers.0.weight"].shape == (1024, 172)
    assert state["_disc_obs_norm._mean_abs"].shape == (172,) and "_disc_obs_norm._mean" not in state
    assert state["_disc_obs_norm._count"].item() == 384

    r = mimickit(
        "test", *common, "--num_envs", "2", "--model_file", str(out / "model.pt"), "--test_episodes", "2", "--json"
    )
    assert r.returncode == 0, r.stderr[-3000:]
    result = json.loads(r.stdout.strip().splitlines()[-1])
    assert result["episodes"] >= 2 and 0 < result["mean_episode_length"] <= 300
    assert result["mean_return"] == 0.0, "ADD envs have no task reward (the reference logs 0 too)"
    assert 0.001 < result["tracking"]["pos_err_m"] < 1.0
