"""`--arg_file RUN/args.json`: a training run's record as an arg file, on a real tiny run (the demo config,
2 envs, one iteration, in a fresh process). `mimickit test` with it tests the run's `model.pt` on the
configs as trained, exactly as the original arg file plus `--model_file RUN/model.pt` does, from any
folder; keys that belong to the training (out_dir, mode, the checkpoint it started from) are not taken
over; the command line wins. The hostile cases are in tests/hostile/test_yaml_args.py."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from mimickit.learning import run_folder
from mimickit.runner.args import check_run_args
from mimickit.util import arg_parser
from mimickit.util.arg_parser import COMMAND_LINE, ArgParser
from mimickit.util.paths import PROJECT_DATA_DIR, PROJECT_ROOT

pytestmark = pytest.mark.integration

ARG_FILE = PROJECT_ROOT / "args" / "deepmimic_humanoid_demo_ppo_args.txt"
TEST_ARGS = ["--num_envs", "2", "--test_episodes", "2", "--rand_seed", "0", "--json"]


def mimickit(*args: str, cwd: Path = PROJECT_ROOT) -> subprocess.CompletedProcess[str]:
    cmd = [sys.executable, "-m", "mimickit.cli", *args]
    env = {**os.environ, "PYTHONPATH": str(PROJECT_ROOT)}  # the checkout's package from any folder
    return subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=cwd, env=env)


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("args_json") / "run"
    r = mimickit("train", "--arg_file", str(ARG_FILE), "--num_envs", "2", "--max_samples", "64", "--out_dir", str(out))
    assert r.returncode == 0, r.stderr[-3000:]
    return out


def test_test_with_a_runs_args_json_tests_its_model_as_the_original_arg_file_does(run: Path, tmp_path: Path) -> None:
    by_record = mimickit("test", "--arg_file", str(run / "args.json"), *TEST_ARGS, cwd=tmp_path)  # another folder
    assert by_record.returncode == 0, by_record.stderr[-3000:]
    by_hand = mimickit("test", "--arg_file", str(ARG_FILE), "--model_file", str(run / "model.pt"), *TEST_ARGS)
    assert by_hand.returncode == 0, by_hand.stderr[-3000:]
    got, want = (json.loads(r.stdout.strip().splitlines()[-1]) for r in (by_record, by_hand))
    assert got["episodes"] >= 2 and got["tracking"]["pos_err_m"] > 0
    assert got["episodes"] == want["episodes"] and got["episode_ends"] == want["episode_ends"]
    assert got["mean_return"] == pytest.approx(want["mean_return"], rel=1e-6)
    assert got["tracking"] == pytest.approx(want["tracking"], rel=1e-6)
    assert not (tmp_path / "output").exists()  # no run folder written by a test


def test_the_record_gives_the_runs_arguments_fit_to_test(run: Path) -> None:
    record = str(run / "args.json")
    args = ArgParser()
    args.load_args(["--arg_file", record, "--mode", "test"])
    assert args.parse_string("model_file") == str(run / "model.pt")  # the run's checkpoint
    for key, name in (("env_config", "env_config.yaml"), ("agent_config", "agent_config.yaml")):
        assert args.parse_string(key) == str(run / name) and args.source(key) == record  # the copies as trained
    assert args.parse_string("num_envs") == "2" and args.parse_string("max_samples") == "64"  # kept as recorded
    assert args.parse_string("test_episodes") == "32"  # the run's own (its agent config's)
    assert not args.has_key("out_dir") and args.parse_strings("arg_file") == [record]  # not the original .txt
    assert args.parse_string("mode") == "test" and args.source("mode") == COMMAND_LINE
    check_run_args(args)

    args = ArgParser()
    other = str(PROJECT_DATA_DIR / "models" / "deepmimic_humanoid_demo_model.pt")
    args.load_args(["--arg_file", record, "--mode", "test", "--model_file", other, "--num_envs", "3"])
    assert args.parse_string("model_file") == other and args.parse_string("num_envs") == "3"  # the command line wins

    args = ArgParser()
    args.load_args(["--arg_file", record])  # train: a new run, from scratch, into a folder it must be given
    assert not args.has_key("model_file") and not args.has_key("out_dir") and not args.has_key("mode")
    assert not args.has_key("test_episodes") and args.parse_string("max_samples") == "64"


def test_a_run_folder_without_its_model_is_one_line(run: Path, tmp_path: Path) -> None:
    folder = tmp_path / "copied"
    folder.mkdir()
    for name in ("args.json", "env_config.yaml", "agent_config.yaml", "engine_config.yaml"):
        shutil.copyfile(run / name, folder / name)
    r = mimickit("test", "--arg_file", str(folder / "args.json"), *TEST_ARGS, cwd=tmp_path)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1, r.stderr[-3000:]
    assert lines[0] == f"error: {folder / 'args.json'}: the run folder has no model.pt to test; give --model_file"


def test_the_parser_spells_the_run_folders_names_as_it_does() -> None:
    assert arg_parser.RUN_RECORD_FORMAT == run_folder.ARGS_FORMAT
    assert arg_parser.RUN_RECORD_MODEL == run_folder.MODEL_FILE
    folder = run_folder.RunFolder("r")
    for key, name in arg_parser.RUN_RECORD_CONFIGS.items():
        assert folder.config_file(key.removesuffix("_config")).name == name
