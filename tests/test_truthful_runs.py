"""A run trains what it is asked to, says what it did, and can be repeated (issue 18, trainer side).

Real 2-iteration `mimickit train` runs in fresh processes on the real DeepMimic env (MuJoCo, the
project's humanoid and demo clip, 4-8 envs): args.json and state.json, `--motion_file`, the divergence
guard (learning rate 1e4), seeds, resume with a larger budget, a crash."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from mimickit.envs.env_builder import load_env_configs
from mimickit.learning.run_folder import ExitCode, RunFolder
from mimickit.tools.plot_log import read_events, read_log
from mimickit.util.paths import PROJECT_ROOT
from tests.conftest import DEMO_CLIP, write_shifted_demo_clip
from tests.test_cli_train import ARG_FILE, NUM_ENVS, metrics, mimickit, train_args

pytestmark = pytest.mark.integration

SAMPLES_PER_ITER = NUM_ENVS * 32
TWO_ITERS = str(2 * SAMPLES_PER_ITER)
TIMING = ("time", "wall_time")


def data_rows(out: Path) -> list[dict]:
    return [r for r in metrics(out) if "event" not in r]


def without_timing(row: dict) -> dict:
    return {k: v for k, v in row.items() if k not in TIMING and not k.startswith("time.")}


@pytest.fixture(scope="module")
def baseline(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished 2-iteration run without --rand_seed (so its seed was drawn)."""
    out = tmp_path_factory.mktemp("baseline") / "run"
    r = mimickit(*train_args(out, "--max_samples", TWO_ITERS))
    assert r.returncode == 0, r.stderr[-3000:]
    return out


@pytest.fixture(scope="module")
def shifted_clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_shifted_demo_clip(tmp_path_factory.mktemp("clips") / "squat_shifted.pkl")


def test_run_folder_records_args_seed_versions_and_end_state(baseline: Path) -> None:
    folder = RunFolder(baseline)
    record = folder.read_args()
    assert record is not None
    assert record["argv"][:2] == ["--mode", "train"] and "--num_envs" in record["argv"]
    assert record["args"]["num_envs"] == [str(NUM_ENVS)] and "env_config" in record["args"]  # from the arg file
    eff = record["effective"]
    assert eff["num_envs"] == NUM_ENVS and eff["max_samples"] == 2 * SAMPLES_PER_ITER
    assert eff["devices"] == ["cpu"] and eff["world_size"] == 1 and eff["out_dir"] == str(baseline.resolve())
    assert eff["env_config"] == str(PROJECT_ROOT / "data/envs/deepmimic_humanoid_env.yaml")
    assert eff["motion_file"] == str(DEMO_CLIP) and eff["motion_file_from"] == "env_config"
    assert eff["agent_name"] == "PPO" and eff["model_file"] is None and eff["torch_threads"] >= 1
    assert record["seed_source"] == "drawn" and 0 <= record["seed"] < 2**31
    versions = record["versions"]
    assert versions["torch"] == torch.__version__ and versions["mujoco"] and versions["numpy"] == np.__version__
    assert versions["git_commit"] is None or len(versions["git_commit"]) == 40
    assert record["start_time"] <= folder.read_state().updated_at
    for role in ("engine", "env", "agent"):
        assert folder.config_file(role).is_file(), role

    state = folder.read_state()
    assert state is not None and state.state.value == "finished"
    assert state.reason == f"reached max_samples {2 * SAMPLES_PER_ITER} at iteration 2, {2 * SAMPLES_PER_ITER} samples"
    assert (state.iteration, state.samples) == (2, 2 * SAMPLES_PER_ITER)


def test_recorded_seed_reproduces_every_metrics_row(baseline: Path, tmp_path: Path) -> None:
    seed = RunFolder(baseline).read_args()["seed"]
    out = tmp_path / "again"
    r = mimickit(*train_args(out, "--max_samples", TWO_ITERS, "--rand_seed", str(seed)))
    assert r.returncode == 0, r.stderr[-3000:]
    assert RunFolder(out).read_args()["seed_source"] == "rand_seed"
    first, again = data_rows(baseline), data_rows(out)
    assert len(first) == len(again) == 2
    assert [without_timing(row) for row in again] == [without_timing(row) for row in first]
    assert first[1]["critic_loss"] > 0 and first[1]["test_episodes"] > 0  # real values, compared exactly


def test_motion_file_replaces_the_env_configs_clip(baseline: Path, shifted_clip: Path, tmp_path: Path) -> None:
    out = tmp_path / "shifted"
    seed = str(RunFolder(baseline).read_args()["seed"])
    r = mimickit(*train_args(out, "--max_samples", TWO_ITERS, "--rand_seed", seed, "--motion_file", str(shifted_clip)))
    assert r.returncode == 0, r.stderr[-3000:]
    env_cfg, _ = load_env_configs(out / "env_config.yaml", out / "engine_config.yaml")
    assert env_cfg.motion_file == str(shifted_clip)
    assert (out / "env_config.yaml").read_text().startswith("# ")  # says it was replaced
    eff = RunFolder(out).read_args()["effective"]
    assert eff["motion_file"] == str(shifted_clip) and eff["motion_file_from"] == "--motion_file"
    # Same seed and env count as the baseline: only the clip differs, and so do the tracking rewards.
    pose = [row["reward_terms.pose"] for row in data_rows(out)]
    assert pose != [row["reward_terms.pose"] for row in data_rows(baseline)]


def test_motion_file_in_test_mode_takes_a_clip_or_a_dataset(baseline: Path, shifted_clip: Path, tmp_path: Path) -> None:
    dataset = tmp_path / "dataset.yaml"
    dataset.write_text(f'motions:\n  - file: "{shifted_clip}"\n    weight: 1.0\n')
    common = ["test", "--arg_file", str(ARG_FILE), "--num_envs", "2", "--model_file", str(baseline / "model.pt"),
              "--test_episodes", "2", "--rand_seed", "3", "--json"]  # fmt: skip
    results = []
    for extra in ([], ["--motion_file", str(shifted_clip)], ["--motion_file", str(dataset)]):
        r = mimickit(*common, *extra)
        assert r.returncode == 0, r.stderr[-3000:]
        results.append(json.loads(r.stdout.strip().splitlines()[-1])["tracking"])
    assert results[1] != results[0], "the clip given with --motion_file is the one tracked"
    assert results[2] == results[1], "a dataset of that one clip tracks the same"


@pytest.mark.parametrize("mode", ["train", "test"])
def test_missing_motion_file_is_one_error_line_before_anything_starts(mode: str, tmp_path: Path) -> None:
    out = tmp_path / "run"
    args = train_args(out, "--max_samples", TWO_ITERS)[1:]
    r = mimickit(mode, *args, "--motion_file", str(tmp_path / "does/not/exist.pkl"))
    assert r.returncode == ExitCode.REFUSED
    assert r.stderr.strip() == f"error: --motion_file: file not found: {tmp_path / 'does/not/exist.pkl'}"
    assert not out.exists()


def test_learning_rate_1e4_diverges_with_its_reason_and_a_finite_model(tmp_path: Path) -> None:
    agent_yaml = (PROJECT_ROOT / "data/agents/deepmimic_humanoid_ppo_cpu_agent.yaml").read_text()
    assert agent_yaml.count("learning_rate: 1e-4") == 2
    agent_file = tmp_path / "lr_1e4_agent.yaml"
    agent_file.write_text(agent_yaml.replace("learning_rate: 1e-4", "learning_rate: 1e4"))
    out = tmp_path / "run"
    r = mimickit("train", "--arg_file", str(ARG_FILE), "--num_envs", "8", "--out_dir", str(out),
                 "--max_samples", str(4 * 8 * 32), "--agent_config", str(agent_file))  # fmt: skip
    assert r.returncode == ExitCode.DIVERGED, r.stderr[-3000:]

    state = RunFolder(out).read_state()
    assert state is not None and state.state.value == "diverged"
    reason = state.reason
    assert reason.startswith("diverged at iteration ") and reason.endswith((" is nan", " is inf", " is -inf"))
    assert reason in r.stdout.splitlines()
    assert f"# {reason}" in (out / "log.txt").read_text().splitlines()
    iteration = int(reason.split()[3].rstrip(":"))
    rows = metrics(out)
    assert rows[-1]["iteration"] == iteration
    assert any(isinstance(v, float) and not math.isfinite(v) for v in rows[-1].values()), rows[-1]
    assert "NaN" in (out / "metrics.jsonl").read_text() or "Infinity" in (out / "metrics.jsonl").read_text()
    # plot's reader keeps the NaN (not null, not dropped) so a curve can mark it.
    loss = reason.split(": ")[1].rsplit(" is ", 1)[0].replace(" ", "_")
    assert not np.isfinite(read_log(out)[loss][-1])

    ckpt = torch.load(out / "model.pt", weights_only=True)
    train_state = ckpt.pop("_train_state")
    assert train_state["iteration"] == iteration and state.iteration == iteration  # the start of that iteration
    assert all(bool(torch.isfinite(v).all()) for v in ckpt.values() if v.is_floating_point())
    r = mimickit("test", "--arg_file", str(ARG_FILE), "--num_envs", "2", "--model_file", str(out / "model.pt"),
                 "--test_episodes", "2", "--json")  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]

    # Continued from model.pt with the arg file's agent config (learning rate 1e-4, not the checkpoint's
    # optimiser's 1e4), the diverged iteration is re-run and the run finishes.
    budget = (iteration + 1) * 8 * 32
    r = mimickit("train", "--arg_file", str(ARG_FILE), "--num_envs", "8", "--out_dir", str(out),
                 "--model_file", str(out / "model.pt"), "--max_samples", str(budget))  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    state = RunFolder(out).read_state()
    assert state.state.value == "finished" and state.samples == budget
    assert [row["iteration"] for row in read_events(out)] == [iteration]
    assert list(read_log(out)["iteration"]) == list(range(iteration + 1))  # the diverged row is superseded
    assert np.isfinite(read_log(out)[loss]).all()


def test_resume_needs_a_larger_budget_then_continues_with_a_marker_row(baseline: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    shutil.copytree(baseline, run)
    folder = RunFolder(run)
    before = {name: (run / name).read_bytes() for name in ("state.json", "metrics.jsonl", "args.json", "log.txt")}
    resume = train_args(run, "--model_file", str(run / "model.pt"))

    r = mimickit(*resume, "--max_samples", TWO_ITERS)
    assert r.returncode == ExitCode.REFUSED
    assert r.stderr.strip() == (
        f"error: {run / 'model.pt'} already has {TWO_ITERS} samples, which reaches --max_samples {TWO_ITERS}:"
        " nothing to train (give a larger --max_samples to continue it)"
    )
    assert {name: (run / name).read_bytes() for name in before} == before, "a refused resume touches nothing"

    three = 3 * SAMPLES_PER_ITER
    r = mimickit(*resume, "--max_samples", str(three))
    assert r.returncode == 0, r.stderr[-3000:]
    rows = metrics(run)
    marker = rows[2]
    assert marker["event"] == "resume" and marker["max_samples"] == three
    assert (marker["iteration"], marker["samples"]) == (2, 2 * SAMPLES_PER_ITER)
    assert [(row["iteration"], row["samples"]) for row in data_rows(run)] == [
        (i, SAMPLES_PER_ITER * (i + 1)) for i in range(3)
    ]
    assert data_rows(run)[2]["wall_time"] > data_rows(run)[1]["wall_time"], "the duration adds up"
    assert [e["samples"] for e in read_events(run)] == [2 * SAMPLES_PER_ITER]
    assert len(read_log(run)["samples"]) == 3  # plot reads the marker row as a marker, not as data
    r = mimickit("plot", str(run), "--out", str(tmp_path / "curves.png"))
    assert r.returncode == 0 and (tmp_path / "curves.png").stat().st_size > 0, r.stderr

    state = folder.read_state()
    assert state.state.value == "finished" and (state.iteration, state.samples) == (3, three)
    record = folder.read_args()
    assert record["resume"] == {"model_file": str(run / "model.pt"), "iteration": 2, "samples": 2 * SAMPLES_PER_ITER}
    assert record["effective"]["max_samples"] == three
    first = json.loads(before["args.json"])
    assert first.pop("previous_starts") == []
    assert record["previous_starts"] == [first]  # the first start's seed and values are kept


def test_a_crash_in_training_ends_as_failed_with_its_line(tmp_path: Path) -> None:
    out = tmp_path / "run"
    (out / "model.pt").mkdir(parents=True)  # the first checkpoint cannot be written
    r = mimickit(*train_args(out, "--max_samples", TWO_ITERS))
    assert r.returncode == ExitCode.FAILED
    state = RunFolder(out).read_state()
    assert state is not None and state.state.value == "failed" and "model.pt" in state.reason
    assert "\n" not in state.reason
    assert r.stderr.strip().splitlines()[-1] == f"error: {state.reason}"


def test_max_hours_ends_the_run_as_a_budget_and_a_spent_one_is_refused(tmp_path: Path) -> None:
    """`--max_hours`: training ends once the recorded wall time reaches it, tested and saved as at
    `--max_samples` (state finished, saying so); a resume whose checkpoint has spent it is refused, and
    a larger one trains on. A budget that is not a number > 0 is one line."""
    run = tmp_path / "run"
    tiny = "0.000000001"  # one iteration takes far longer than 3.6 µs: the budget is spent by the first
    r = mimickit(*train_args(run, "--max_samples", str(10 * SAMPLES_PER_ITER), "--max_hours", tiny))
    assert r.returncode == 0, r.stderr[-3000:]
    state = RunFolder(run).read_state()
    assert state.state.value == "finished" and (state.iteration, state.samples) == (1, SAMPLES_PER_ITER)
    assert state.reason == f"reached max_hours 1e-09 of recorded wall time at iteration 1, {SAMPLES_PER_ITER} samples"
    assert f"finished: {state.reason}" in r.stdout
    (row,) = data_rows(run)
    assert row["wall_time"] >= 1e-9 and "test_return" in row  # the last iteration was tested
    assert (run / "model.pt").is_file()
    assert RunFolder(run).read_args()["effective"]["max_hours"] == 1e-9

    resume = train_args(run, "--model_file", str(run / "model.pt"), "--max_samples", TWO_ITERS)
    r = mimickit(*resume, "--max_hours", tiny)
    assert r.returncode == ExitCode.REFUSED
    assert r.stderr.startswith(f"error: {run / 'model.pt'} already has ") and r.stderr.strip().endswith(
        "h of training, which reaches --max_hours 1e-09: nothing to train (give a larger --max_hours to continue it)"
    )
    r = mimickit(*resume, "--max_hours", "1")
    assert r.returncode == 0, r.stderr[-3000:]
    assert RunFolder(run).read_state().reason == f"reached max_samples {TWO_ITERS} at iteration 2, {TWO_ITERS} samples"

    for bad in ("0", "-1", "nan", "soon"):
        r = mimickit(*train_args(tmp_path / "bad", "--max_hours", bad))
        assert r.returncode == ExitCode.REFUSED and r.stderr.count("\n") == 1, r.stderr
        assert r.stderr.startswith("error: --max_hours"), r.stderr
