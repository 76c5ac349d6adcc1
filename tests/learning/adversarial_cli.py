"""Shared steps of the adversarial agents' CLI tests (AMP, ADD, ASE): a short `mimickit train` of 4 envs
and a `mimickit test --json` of its checkpoint, each in a fresh process, and the checks every
discriminator run shares."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.test_cli_train import metrics, mimickit

OUTPUT_FILES = ("log.txt", "metrics.jsonl", "model.pt", "env_config.yaml", "agent_config.yaml")


def train_short(arg_file: Path, out: Path, max_samples: int, *extra: str) -> list[dict]:
    """Train 4 envs (seed 0) up to `max_samples`; return the metrics rows after checking the outputs."""
    r = mimickit(
        "train", "--arg_file", str(arg_file), "--num_envs", "4", "--max_samples", str(max_samples),
        "--out_dir", str(out), "--rand_seed", "0", *extra,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    for name in OUTPUT_FILES:
        assert (out / name).is_file(), name
    return metrics(out)


def test_json(arg_file: Path, model_file: Path, *extra: str) -> dict:
    """`mimickit test --json` of 2 episodes on 2 envs; the printed result."""
    r = mimickit(
        "test", "--arg_file", str(arg_file), "--num_envs", "2", "--model_file", str(model_file),
        "--test_episodes", "2", "--json", *extra,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    result = json.loads(r.stdout.strip().splitlines()[-1])
    assert result["episodes"] >= 2 and 0 < result["mean_episode_length"] <= 300
    return result


test_json.__test__ = False  # a helper, not a test pytest should collect


def check_disc_log(out: Path, disc_columns: list[str]) -> list[str]:
    """The reference's log.txt order: disc terms after the actor's, disc reward after the advantages.
    Returns the header for further checks."""
    header = (out / "log.txt").read_text().splitlines()[0].split()
    i = header.index("Action_Bound_Loss")
    assert header[i + 1 : i + 1 + len(disc_columns)] == disc_columns
    j = i + 1 + len(disc_columns)
    assert header[j : j + 4] == ["Adv_Mean", "Adv_Std", "Disc_Reward_Mean", "Disc_Reward_Std"]
    return header


def check_disc_rows(rows: list[dict], disc_columns: list[str]) -> None:
    """Every iteration logs each disc column, and the env's per-step style reward is the reward the agent
    trains on (no task reward in these envs)."""
    for row in rows:
        for key in [c.lower() for c in disc_columns] + ["disc_reward_mean", "disc_reward_std"]:
            assert key in row and row[key] is not None, key
        assert row["reward_terms.disc"] == pytest.approx(row["disc_reward_mean"], rel=1e-4)
        assert row["reward_terms.task"] == 0.0
