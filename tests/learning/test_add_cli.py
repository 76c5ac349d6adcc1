"""`mimickit train` / `mimickit test` with the shipped ADD arg file, in fresh processes: the humanoid ADD
env (MuJoCo) on MimicKit's walk clip (`--data_dir`, reference data) and the reference agent yaml,
three iterations of 4 envs."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from mimickit.util.paths import PROJECT_ROOT
from tests.learning.adversarial_cli import check_disc_log, check_disc_rows, test_json, train_short

pytestmark = pytest.mark.integration

ARG_FILE = PROJECT_ROOT / "args" / "add_humanoid_args.txt"
DISC_COLUMNS = [
    "Disc_Loss", "Disc_Grad_Penalty", "Disc_Logit_Loss", "Disc_Pos_Acc", "Disc_Neg_Acc", "Disc_Pos_Logit",
    "Disc_Neg_Logit",
]  # fmt: skip
TRACKING = ["root_pos_err", "root_rot_err", "body_pos_err", "body_rot_err", "dof_vel_err", "root_vel_err",
            "root_ang_vel_err"]  # fmt: skip


def test_add_train_writes_outputs_and_the_checkpoint_tests_in_a_fresh_process(tmp_path: Path, test_data: Path) -> None:
    out = tmp_path / "run"
    data = ["--data_dir", str(test_data)]
    rows = train_short(ARG_FILE, out, 384, *data)
    assert "humanoid_walk.pkl" in (out / "env_config.yaml").read_text()
    header = check_disc_log(out, DISC_COLUMNS)
    i = header.index("Disc_Reward_Std") + 1
    assert [c.title() for c in TRACKING] == header[i : i + 7], "log_tracking_error: the test-mode means"

    assert [m["samples"] for m in rows] == [128, 256, 384]
    check_disc_rows(rows, DISC_COLUMNS)
    for row in rows:
        assert 0.0 <= row["disc_pos_acc"] <= 1.0 and 0.0 <= row["disc_neg_acc"] <= 1.0
        assert all(row[f"tracking.{k}"] >= 0.0 for k in TRACKING)
    # Any drift from the clip is a negative: the discriminator ranks the zero difference above them.
    assert rows[-1]["disc_neg_logit"] < rows[-1]["disc_pos_logit"]

    state = torch.load(out / "model.pt", weights_only=True)
    assert state["_model._disc_layers.0.weight"].shape == (1024, 172)
    assert state["_disc_obs_norm._mean_abs"].shape == (172,) and "_disc_obs_norm._mean" not in state
    assert state["_disc_obs_norm._count"].item() == 384

    result = test_json(ARG_FILE, out / "model.pt", *data)
    assert result["mean_return"] == 0.0, "ADD envs have no task reward (the reference logs 0 too)"
    assert 0.001 < result["tracking"]["pos_err_m"] < 1.0
