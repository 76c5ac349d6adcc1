"""`mimickit bench --train` as a user runs it: a fresh process, the real DeepMimic env and PPO agent."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from mimickit.util.paths import PROJECT_ROOT

pytestmark = pytest.mark.integration


def bench(*args: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "mimickit.cli", "bench", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=PROJECT_ROOT)


def test_train_bench_json_splits_the_training_time():
    r = bench("--train", "--num_envs", "8", "--rounds", "2", "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["agent"] == "PPO" and out["num_envs"] == 8 and out["steps_per_iter"] == 32
    # The ratio is printed to 4 decimals: on a loaded machine it is small, so compare absolutely.
    assert out["train_ratio"] == pytest.approx(out["train_samples_per_s"] / out["env_steps_per_s"], abs=1e-4)
    assert len(out["train_ratio_per_round"]) == 2
    assert set(out["train_split"]) == {"sim", "inference", "update", "other"}
    assert sum(out["train_split"].values()) == pytest.approx(1.0, abs=1e-3)
    assert out["train_split"]["update"] > 0 and out["train_split"]["sim"] > 0


def test_train_bench_text_names_the_agent_file():
    r = bench("--train", "--num_envs", "4", "--rounds", "1")
    assert r.returncode == 0, r.stderr
    assert "deepmimic_humanoid_ppo_cpu_agent.yaml" in r.stdout and "train_ratio" in r.stdout


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--train", "--steps", "5"], "--steps and --raw"),
        (["--train", "--raw", "replay"], "--steps and --raw"),
        (["--agent_config", "data/agents/amp_humanoid_cpu_agent.yaml"], "--agent_config is read only with --train"),
        (["--train", "--agent_config", "data/agents/nope.yaml"], "nope.yaml"),
    ],
)
def test_train_bench_refuses_arguments_it_would_ignore(args, message):
    r = bench(*args, "--num_envs", "4")
    assert r.returncode != 0
    assert message in r.stderr and "Traceback" not in r.stderr
