"""`mimickit eval`: the demo policy on a two-clip dataset (real MuJoCo, a real CLI process); exactly the
episodes asked for, and a start just before a non-looping clip's end weighing its few steps in the
time-weighted full length; bad input as one error line."""

from __future__ import annotations

import dataclasses
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import yaml

from mimickit import cli
from mimickit.anim.motion import LoopMode, load_motion, save_motion
from mimickit.runner import policy
from mimickit.tools.evaluate import EvalClip, clip_row, count_episodes, episode_quota, format_table
from mimickit.util.paths import PROJECT_DATA_DIR, PROJECT_ROOT
from tests.conftest import DEMO_CLIP

pytestmark = pytest.mark.integration

DEMO_MODEL = PROJECT_DATA_DIR / "models" / "deepmimic_humanoid_demo_model.pt"
DEMO_ARGS = PROJECT_DATA_DIR / "models" / "deepmimic_humanoid_demo_model.txt"
EPISODE_STEPS = 300  # the demo env: 10 s episodes at 30 Hz
ERROR_KEYS = ("pos_err_m", "paper_pos_err_m", "paper_dof_vel_err")


def write_dataset(path: Path, entries: list[tuple[str, float]]) -> Path:
    path.write_text(yaml.safe_dump({"motions": [{"file": f, "weight": w} for f, w in entries]}))
    return path


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """`mimickit eval --json` over the demo clip listed twice (weights 1 and 3), 2 envs, 2 episodes each."""
    dataset = write_dataset(
        tmp_path_factory.mktemp("eval") / "two.yaml",
        [(str(DEMO_CLIP), 1.0), ("data/motions/humanoid_demo_squat.pkl", 3.0)],
    )
    cmd = [sys.executable, "-m", "mimickit.cli", "eval", "--arg_file", str(DEMO_ARGS), "--model_file", str(DEMO_MODEL)]
    cmd += ["--motion_file", str(dataset), "--episodes", "2", "--num_envs", "2", "--json"]
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=PROJECT_ROOT, timeout=300)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


def test_one_row_per_dataset_entry_in_range(report: dict) -> None:
    rows = report["rows"]
    assert [(r["clip"], r["weight"]) for r in rows] == [
        (str(DEMO_CLIP), 1.0),
        ("data/motions/humanoid_demo_squat.pkl", 3.0),
    ]
    for row in rows:
        assert row["episodes"] == 2 and row["failed"] == 0
        assert row["steps"] == row["available_steps"] == round(2 * row["mean_ep_len"])
        assert 0 < row["mean_ep_len"] <= EPISODE_STEPS
        assert 0.0 <= row["full_length_frac"] <= 1.0
        for key in ERROR_KEYS:
            assert 0.0 < row[key] < 2.0, (key, row)
    # the demo policy squats on for whole episodes (its arg file: 300.0 of 300 steps), ~0.14 m off
    assert rows[0]["full_length_frac"] == 1.0 and rows[0]["mean_ep_len"] == EPISODE_STEPS
    assert rows[0]["paper_pos_err_m"] < 0.3
    # the paper's position error adds the root's global error to the root-relative one
    assert rows[0]["paper_pos_err_m"] != rows[0]["pos_err_m"]


def test_each_clip_starts_from_the_same_seed(report: dict) -> None:
    """The same clip twice: the same figures (a row does not depend on the clips before it)."""
    first, second = ({k: v for k, v in r.items() if k not in ("clip", "weight")} for r in report["rows"])
    assert first == second


def test_mean_pools_the_rows(report: dict) -> None:
    """Lengths and returns weighted by episodes, the full length by available steps, errors by steps."""
    rows, mean = report["rows"], report["mean"]
    assert mean["clips"] == 2
    for key in ("episodes", "failed", "steps", "available_steps"):
        assert mean[key] == sum(r[key] for r in rows), key
    for key, weight in (("mean_ep_len", "episodes"), ("full_length_frac", "available_steps"), ("pos_err_m", "steps")):
        expected = sum(r[key] * r[weight] for r in rows) / mean[weight]
        assert mean[key] == pytest.approx(expected), key


def test_table_has_a_line_per_clip_and_the_mean(report: dict) -> None:
    lines = format_table(report).splitlines()
    assert lines[0].split()[:6] == ["clip", "weight", "episodes", "failed", "mean_ep_len", "full_time"]
    assert len(lines) == 4 and lines[3].startswith("mean (2 clips)")
    assert f"{report['rows'][0]['paper_pos_err_m']:.4f}" in lines[1]


@pytest.fixture
def misfit_model(tmp_path: Path) -> Path:
    """The demo checkpoint with its observation normaliser one value short: it fits no humanoid env."""
    state = torch.load(DEMO_MODEL, weights_only=True)
    state["_obs_norm._mean"] = state["_obs_norm._mean"][:-1].clone()
    path = tmp_path / "misfit.pt"
    torch.save(state, path)
    return path


def run_main(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = cli.main(["eval", "--arg_file", str(DEMO_ARGS), *argv])
    out, err = capsys.readouterr()
    return code, out, err


def bad_yaml(tmp: Path) -> list[str]:
    (tmp / "bad.yaml").write_text("motions: [file: {")
    return ["--model_file", str(DEMO_MODEL), "--motion_file", str(tmp / "bad.yaml")]


def missing_clip(tmp: Path) -> list[str]:
    ds = write_dataset(tmp / "ds.yaml", [(str(DEMO_CLIP), 1.0), ("data/motions/no_such_clip.pkl", 1.0)])
    return ["--model_file", str(DEMO_MODEL), "--motion_file", str(ds)]


def misspelt_key(tmp: Path) -> list[str]:
    (tmp / "ds.yaml").write_text(f"motions:\n  - file: {DEMO_CLIP}\n    wieght: 2\n")
    return ["--model_file", str(DEMO_MODEL), "--motion_file", str(tmp / "ds.yaml")]


def not_a_clip(tmp: Path) -> list[str]:
    (tmp / "junk.pkl").write_bytes(b"\x80\x04not a pickle")
    return ["--model_file", str(DEMO_MODEL), "--motion_file", str(tmp / "junk.pkl")]


@pytest.mark.parametrize(
    ("make_argv", "expected"),
    [
        pytest.param(bad_yaml, "bad.yaml", id="err-dataset-yaml-does-not-parse"),
        pytest.param(missing_clip, "motions[1].file not found: data/motions/no_such_clip.pkl", id="err-unknown-clip"),
        pytest.param(misspelt_key, "wieght", id="err-dataset-unknown-key"),
        pytest.param(not_a_clip, "junk.pkl", id="err-clip-not-a-pickle"),
        pytest.param(
            lambda t: ["--model_file", str(DEMO_MODEL), "--motion_file", "nope.pkl"],
            "nope.pkl",
            id="err-no-such-motion-file",
        ),
        pytest.param(lambda t: ["--model_file", str(t / "none.pt")], "none.pt", id="err-no-such-model"),
        pytest.param(
            lambda t: ["--model_file", str(DEMO_MODEL), "--episodes", "0"], "--episodes", id="err-zero-episodes"
        ),
    ],
)
def test_bad_input_is_one_error_line(
    make_argv, expected: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = run_main(make_argv(tmp_path), capsys)
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and err.startswith("error: ") and expected in err, err


def test_checkpoint_that_does_not_fit_is_one_error_line(misfit_model: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_main(["--model_file", str(misfit_model), "--episodes", "1", "--num_envs", "1"], capsys)
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and "misfit.pt" in err and "_obs_norm._mean" in err, err


def test_falls_count_against_full_length(test_data: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The walk policy on MimicKit's run clip falls within a second: short episodes, few full-length."""
    walk_args = PROJECT_DATA_DIR / "models" / "deepmimic_humanoid_walk_model.txt"
    walk_model = PROJECT_DATA_DIR / "models" / "deepmimic_humanoid_walk_model.pt"
    argv = ["eval", "--arg_file", str(walk_args), "--model_file", str(walk_model), "--data_dir", str(test_data)]
    argv += ["--motion_file", "data/motions/humanoid/humanoid_run.pkl", "--episodes", "2", "--num_envs", "2", "--json"]
    assert cli.main(argv) == 0
    (row,) = json.loads(capsys.readouterr().out)["rows"]
    assert row["clip"] == "data/motions/humanoid/humanoid_run.pkl" and row["episodes"] == 2 and row["failed"] >= 1
    assert row["mean_ep_len"] < EPISODE_STEPS / 2 and row["full_length_frac"] < 0.5, row


def test_quota_spreads_the_episodes_over_the_envs() -> None:
    assert episode_quota(2, 2) == [1, 1]
    assert episode_quota(5, 2) == [3, 2]
    assert episode_quota(7, 3) == [3, 2, 2]
    assert sum(episode_quota(256, 16)) == 256


def test_more_envs_than_episodes_still_counts_the_episodes_asked(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["eval", "--arg_file", str(DEMO_ARGS), "--model_file", str(DEMO_MODEL), "--motion_file", str(DEMO_CLIP)]
    assert cli.main([*argv, "--episodes", "1", "--num_envs", "3", "--json"]) == 0
    (row,) = json.loads(capsys.readouterr().out)["rows"]
    assert row["episodes"] == 1 and row["steps"] == EPISODE_STEPS


@pytest.fixture
def short_clamped_clip(tmp_path: Path) -> Path:
    """The first 60 frames (about 2 s) of the demo squat, not looping: its episodes end at its end."""
    demo = load_motion(DEMO_CLIP)
    path = tmp_path / "short_squat.pkl"
    save_motion(path, dataclasses.replace(demo, frames=demo.frames[:60].copy(), loop_mode=LoopMode.CLAMP))
    return path


def walk_policy_on(clip: Path, starts: list[float]) -> tuple[object, object, int]:
    """The walk policy in 2 envs of `clip` (it falls trying to squat), env i starting at `starts[i]`
    seconds (negative: that many before the clip's end); and the clip's length in control steps."""
    walk = PROJECT_DATA_DIR / "models" / "deepmimic_humanoid_walk_model"
    inputs = dataclasses.replace(policy.policy_inputs(walk.with_suffix(".txt")), motion_file=str(clip))
    env, agent = policy.load_policy(inputs, walk.with_suffix(".pt"), num_envs=2)
    length = float(env.motion_lib.get_motion_length(torch.tensor([0])))
    times = torch.tensor([length + t if t < 0 else t for t in starts])
    env.start_next_resets_at(torch.zeros(2, dtype=torch.long), times)
    return env, agent, math.ceil(length / env.engine.get_timestep() - 1e-3)


def test_a_start_just_before_a_non_looping_clips_end_weighs_only_its_steps(short_clamped_clip: Path) -> None:
    """2 episodes, 2 envs: env 0 starts 0.1 s before the clip's end (3 steps at 30 Hz, then the clip ends
    it: not a failure), env 1 at the clip's start, and the walk policy falls trying to squat. Counted
    per episode, half the episodes would be "full"; weighted by the time each had, the fall dominates."""
    torch.manual_seed(0)
    env, agent, clip_steps = walk_policy_on(short_clamped_clip, [-0.1, 0.0])
    try:
        totals = count_episodes(agent, env, 2)
    finally:
        env.engine.close()
    assert totals.episodes == 2 and totals.failed == 1
    fall_steps = totals.steps - 3
    assert 0 < fall_steps < clip_steps  # env 1 fell before the clip's end
    assert totals.available_steps == 3 + clip_steps  # what each episode had: 3 steps, the whole clip
    row = clip_row(EvalClip("short", short_clamped_clip, 1.0), totals)
    assert row["full_length_frac"] == pytest.approx((3 + fall_steps) / (3 + clip_steps))
    assert row["full_length_frac"] < 0.75 and row["mean_ep_len"] == totals.steps / 2

    # `mimickit test` keeps the reference's count: env 0 runs more episodes while env 1 is up, and every
    # one that ends counts, so 2 episodes come back as more.
    torch.manual_seed(0)
    env, agent, _ = walk_policy_on(short_clamped_clip, [-0.1, 0.0])
    try:
        reference = policy.test_result(agent, env, 2)
    finally:
        env.engine.close()
    assert reference["episodes"] > 2 and reference["episode_ends"]["fail"] >= 1
