"""Short DeepMimic runs on the Unitree G1 and the Unitree Go2, and a short ADD run on the Go2, through
`mimickit train` in a fresh process (MimicKit's assets and clips from `$MIMICKIT_TEST_DATA` via `--data_dir`),
each checkpoint reloaded by `mimickit test`."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from mimickit.util.paths import PROJECT_ROOT

pytestmark = pytest.mark.integration

NUM_ENVS = 4  # 32 steps per iteration: 128 samples


def mimickit(*args: str | Path, timeout: float = 300) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "mimickit.cli", *map(str, args)]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, cwd=PROJECT_ROOT)


@pytest.mark.parametrize("char", ["g1", "go2"])
def test_deepmimic_trains_and_its_checkpoint_reloads(char: str, test_data: Path, tmp_path: Path) -> None:
    arg_file = PROJECT_ROOT / f"args/deepmimic_{char}_ppo_args.txt"
    common = ["--arg_file", arg_file, "--data_dir", test_data, "--num_envs", NUM_ENVS]
    out = tmp_path / "run"
    r = mimickit("train", *common, "--max_samples", 256, "--out_dir", out, "--rand_seed", 0)
    assert r.returncode == 0, r.stderr[-3000:]
    rows = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert [m["samples"] for m in rows] == [128, 256]
    for m in rows:
        assert math.isfinite(m["critic_loss"]) and m["train_return"] > 0 and m["time.samples_per_s"] > 0
        assert {"reward_terms.pose", "reward_terms.key_pos"} <= set(m)
    assert (out / "model.pt").is_file()

    r = mimickit("test", *common, "--model_file", out / "model.pt", "--test_episodes", 4, "--json")
    assert r.returncode == 0, r.stderr[-3000:]
    result = json.loads(r.stdout.strip().splitlines()[-1])
    assert result["episodes"] >= 4 and 0 < result["mean_episode_length"] <= 300
    assert math.isfinite(result["mean_return"]) and result["mean_return"] > 0


def test_add_go2_trains_and_its_checkpoint_reloads(test_data: Path, tmp_path: Path) -> None:
    """ADD on the Go2 (174-value differences): two iterations, disc metrics and tracking in metrics.jsonl, the
    disc and its DiffNormalizer sized for the Go2 in the checkpoint, and `mimickit test` reloading it."""
    common = ["--arg_file", PROJECT_ROOT / "args/add_go2_args.txt", "--data_dir", test_data, "--num_envs", NUM_ENVS]
    out = tmp_path / "run"
    r = mimickit("train", *common, "--max_samples", 256, "--out_dir", out, "--rand_seed", 0)
    assert r.returncode == 0, r.stderr[-3000:]
    rows = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert [m["samples"] for m in rows] == [128, 256]
    for m in rows:
        assert math.isfinite(m["disc_loss"]) and 0.0 <= m["disc_neg_acc"] <= 1.0
        assert m["reward_terms.disc"] > 0 and m["reward_terms.task"] == 0.0
        assert m["tracking.body_pos_err"] >= 0.0
    state = torch.load(out / "model.pt", weights_only=True)
    assert state["_model._disc_layers.0.weight"].shape == (1024, 174)
    assert state["_disc_obs_norm._mean_abs"].shape == (174,)

    r = mimickit("test", *common, "--model_file", out / "model.pt", "--test_episodes", 4, "--json")
    assert r.returncode == 0, r.stderr[-3000:]
    result = json.loads(r.stdout.strip().splitlines()[-1])
    assert result["episodes"] >= 4 and 0 < result["mean_episode_length"] <= 300
    assert result["mean_return"] == 0.0 and 0.0 < result["tracking"]["pos_err_m"] < 1.0
