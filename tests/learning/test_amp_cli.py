"""`mimickit train` / `mimickit test` with the shipped AMP arg file, in fresh processes: the real
humanoid AMP env (MuJoCo) and the reference agent yaml, three iterations of 4 envs."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from mimickit.util.paths import PROJECT_ROOT
from tests.learning.adversarial_cli import check_disc_log, check_disc_rows, test_json, train_short

pytestmark = pytest.mark.integration

ARG_FILE = PROJECT_ROOT / "args" / "amp_humanoid_args.txt"
DISC_COLUMNS = [
    "Disc_Loss", "Disc_Grad_Penalty", "Disc_Agent_Acc", "Disc_Demo_Acc", "Disc_Agent_Logit", "Disc_Demo_Logit",
    "Disc_Logit_Loss",
]  # fmt: skip


def test_amp_train_writes_disc_metrics_and_the_checkpoint_tests_in_a_fresh_process(tmp_path: Path) -> None:
    out = tmp_path / "run"
    rows = train_short(ARG_FILE, out, 384)
    check_disc_log(out, DISC_COLUMNS)
    assert [m["samples"] for m in rows] == [128, 256, 384]
    check_disc_rows(rows, DISC_COLUMNS)
    for row in rows:
        assert 0.0 <= row["disc_agent_acc"] <= 1.0 and 0.0 <= row["disc_demo_acc"] <= 1.0
    assert rows[-1]["disc_agent_logit"] < rows[-1]["disc_demo_logit"], "the discriminator tells the clip apart"

    state = torch.load(out / "model.pt", weights_only=True)
    assert state["_model._disc_layers.0.weight"].shape == (1024, 1420)
    assert state["_disc_obs_norm._mean"].shape == (1420,)

    result = test_json(ARG_FILE, out / "model.pt")
    assert result["mean_return"] == 0.0, "AMP envs have no task reward (the reference logs 0 too)"
