"""`mimickit train` / `mimickit test` with the shipped ASE arg file, in fresh processes: the real
humanoid ASE env (MuJoCo) and the reference agent yaml, two iterations of 4 envs."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from mimickit.util.paths import PROJECT_ROOT
from tests.learning.adversarial_cli import test_json, train_short

pytestmark = pytest.mark.integration

ARG_FILE = PROJECT_ROOT / "args" / "ase_humanoid_args.txt"


def test_ase_train_writes_enc_metrics_and_the_checkpoint_tests_in_a_fresh_process(tmp_path: Path) -> None:
    out = tmp_path / "run"
    rows = train_short(ARG_FILE, out, 256)
    assert [m["samples"] for m in rows] == [128, 256]
    for row in rows:
        for key in ("disc_loss", "disc_agent_acc", "enc_loss", "diversity_loss", "enc_reward_mean", "disc_reward_mean"):
            assert key in row and row[key] is not None, key
        # z·ẑ of unit vectors: the loss is a negated mean cosine, the reward its positive part.
        assert -1.0 <= row["enc_loss"] <= 1.0 and 0.0 <= row["enc_reward_mean"] <= 1.0
        assert row["diversity_loss"] >= 0.0
        # The env's per-step terms are the rewards the agent trains on.
        assert row["reward_terms.disc"] == pytest.approx(row["disc_reward_mean"], rel=1e-4)
        assert row["reward_terms.enc"] == pytest.approx(row["enc_reward_mean"], rel=1e-4)
        assert row["reward_terms.task"] == 0.0

    state = torch.load(out / "model.pt", weights_only=True)
    assert state["_model._actor_layers.0.weight"].shape == (1024, 140 + 64)
    assert state["_model._critic_layers.0.weight"].shape == (1024, 140 + 64)
    assert state["_model._enc_layers.0.weight"].shape == (1024, 1420)
    assert state["_model._enc_out.weight"].shape == (64, 512)  # fc_2layers_1024units ends in 512
    assert state["_disc_obs_norm._mean"].shape == (1420,)

    test_json(ARG_FILE, out / "model.pt")
