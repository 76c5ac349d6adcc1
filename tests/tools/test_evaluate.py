"""`mimickit eval`: the demo policy on a two-clip dataset (real MuJoCo, a real CLI process), and bad input
as one error line."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import yaml

from mimickit import cli
from mimickit.tools.evaluate import format_table
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
        assert row["episodes"] >= 2
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


def test_mean_is_weighted_by_episodes(report: dict) -> None:
    rows, mean = report["rows"], report["mean"]
    assert mean["clips"] == 2 and mean["episodes"] == sum(r["episodes"] for r in rows)
    for key in ("mean_ep_len", "full_length_frac", *ERROR_KEYS):
        expected = sum(r[key] * r["episodes"] for r in rows) / mean["episodes"]
        assert mean[key] == pytest.approx(expected)


def test_table_has_a_line_per_clip_and_the_mean(report: dict) -> None:
    lines = format_table(report).splitlines()
    assert lines[0].split()[:3] == ["clip", "weight", "episodes"]
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
    assert row["clip"] == "data/motions/humanoid/humanoid_run.pkl" and row["episodes"] >= 2
    assert row["mean_ep_len"] < EPISODE_STEPS / 2 and row["full_length_frac"] < 0.5, row
