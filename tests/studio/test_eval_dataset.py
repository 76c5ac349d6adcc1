"""`mimickit eval` over a two-clip dataset (the demo clip and a shortened, non-looping copy of it), as the
CLI prints it and as the studio's eval job gives it: one row per clip, in the dataset's order, named as
the dataset writes them, with exactly the episodes asked for, and the mean row pooling the rows; then a
row of the job rolled out plays that row's clip (the rollout's `motion_files`)."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from mimickit.util.paths import PROJECT_ROOT
from tests.studio.conftest import DEMO_CLIP_NAME, StudioProcess, wait_for, write_demo_dataset

pytestmark = pytest.mark.integration

SHIPPED = "data/models/deepmimic_humanoid_demo_model.pt"
DEMO_ARGS = "data/models/deepmimic_humanoid_demo_model.txt"
EPISODES = 2
EPISODE_STEPS = 300  # the demo env: 10 s episodes at 30 Hz
MEAN_WEIGHTS = {
    "mean_ep_len": "episodes",
    "mean_return": "episodes",
    "full_length_frac": "available_steps",
    "pos_err_m": "steps",
    "paper_pos_err_m": "steps",
    "paper_dof_vel_err": "steps",
}
MEAN_KEYS = tuple(MEAN_WEIGHTS)


@pytest.fixture(scope="module")
def runs_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("eval_dataset_runs")


@pytest.fixture(scope="module")
def dataset(runs_dir: Path) -> tuple[Path, Path]:
    """In the runs folder: a file the studio may read."""
    return write_demo_dataset(runs_dir / "datasets")


@pytest.fixture(scope="module")
def cli_report(dataset: tuple[Path, Path]) -> dict:
    cmd = [sys.executable, "-m", "mimickit.cli", "eval", "--arg_file", DEMO_ARGS, "--model_file", SHIPPED]
    cmd += ["--motion_file", str(dataset[0]), "--episodes", str(EPISODES), "--json"]
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=PROJECT_ROOT, timeout=300)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


@pytest.fixture(scope="module")
def server(runs_dir: Path) -> Iterator[StudioProcess]:
    s = StudioProcess(runs_dir, None)
    yield s
    s.stop()


def test_cli_gives_one_row_per_clip_and_their_pooled_mean(cli_report: dict, dataset: tuple[Path, Path]) -> None:
    rows, mean = cli_report["rows"], cli_report["mean"]
    assert [(r["clip"], r["weight"]) for r in rows] == [(DEMO_CLIP_NAME, 1.0), (str(dataset[1]), 2.0)]
    demo, short = rows
    # 2 envs on the looping demo clip: both run the whole 10 s episode, one episode each.
    assert demo["episodes"] == EPISODES and demo["mean_ep_len"] == EPISODE_STEPS
    # The short clip ends after 1.5 s: each env's first episode is much shorter, and only it counts
    # (the reference's count, `mimickit test`'s, would take every episode that ends meanwhile).
    assert short["episodes"] == EPISODES and short["mean_ep_len"] < 45
    assert mean["clips"] == 2 and mean["episodes"] == 2 * EPISODES
    for key, weight in MEAN_WEIGHTS.items():
        pooled = (demo[key] * demo[weight] + short[key] * short[weight]) / (demo[weight] + short[weight])
        assert mean[key] == pytest.approx(pooled), key
    # Errors weighted by steps: the short clip's few steps move the mean little.
    assert mean["pos_err_m"] != pytest.approx((demo["pos_err_m"] + short["pos_err_m"]) / 2)


def test_an_eval_job_over_the_dataset_gives_the_same_rows_and_a_row_rolls_out_its_clip(
    server: StudioProcess, cli_report: dict, dataset: tuple[Path, Path]
) -> None:
    body = {"checkpoint": SHIPPED, "arg_file": DEMO_ARGS, "motion_file": str(dataset[0]), "episodes": EPISODES}
    r = server.post("/api/evals", body)
    assert r.status_code == 201, r.text
    job_id = r.json()["id"]
    done = wait_for(
        lambda: (j := server.get(f"/api/evals/{job_id}").json())["status"] in ("finished", "failed") and j,
        300,
        "the dataset eval to end",
    )
    assert done["status"] == "finished", done["error"]
    assert len(done["rows"]) == 2
    for got, want in zip(done["rows"], cli_report["rows"], strict=True):
        assert (got["clip"], got["weight"], got["episodes"]) == (want["clip"], want["weight"], want["episodes"])
        for key in MEAN_KEYS:
            assert got[key] == pytest.approx(want[key], rel=1e-5), (got["clip"], key)
    assert done["mean"]["clips"] == 2 and done["mean"]["episodes"] == cli_report["mean"]["episodes"]
    assert done["mean"]["mean_ep_len"] == pytest.approx(cli_report["mean"]["mean_ep_len"], rel=1e-5)

    rolled = server.post(f"/api/evals/{job_id}/rollout", {"row": 1, "play": False})
    assert rolled.status_code == 200, rolled.text
    try:
        rollout = rolled.json()["rollout"]
        assert [Path(p).resolve() for p in rollout["motion_files"]] == [dataset[1].resolve()]
        assert rollout["checkpoint"].endswith("deepmimic_humanoid_demo_model.pt")
    finally:
        server.post("/api/scene/rollout/close")
