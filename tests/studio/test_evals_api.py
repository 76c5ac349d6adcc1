"""Eval jobs through the real server: `mimickit eval --json` of a checkpoint as a subprocess in the
job's own folder, its table, a failure reported in one line, a rollout of one row's clip, and requests
that name files outside the allowed folders."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.studio.conftest import StudioProcess, wait_for, write_arg_file

pytestmark = pytest.mark.integration

SHIPPED = "data/models/deepmimic_humanoid_demo_model.pt"


def finished(studio: StudioProcess, job_id: int, timeout: float = 240.0) -> dict:
    return wait_for(
        lambda: (j := studio.get(f"/api/evals/{job_id}").json())["status"] in ("finished", "failed") and j,
        timeout,
        f"eval {job_id} to end",
    )


def test_eval_of_the_shipped_model_and_a_row_rolled_out(studio: StudioProcess) -> None:
    r = studio.post("/api/evals", {"checkpoint": SHIPPED, "episodes": 1})
    assert r.status_code == 201, r.text
    job = r.json()
    assert job["status"] in ("queued", "running") and "--json" in job["command"]
    folder = Path(job["folder"])
    assert folder.parent == studio.runs_dir / "evals"
    done = finished(studio, job["id"])
    assert done["status"] == "finished", done["error"]
    (row,) = done["rows"]
    assert row["clip"] == "data/motions/humanoid_demo_squat.pkl" and row["episodes"] >= 1
    assert 0 < row["mean_ep_len"] <= 300 and 0 <= row["full_length_frac"] <= 1 and row["pos_err_m"] > 0
    assert done["mean"]["clips"] == 1
    assert (folder / "report.json").is_file() and (folder / "console.log").is_file()  # its own working folder
    assert any(j["id"] == job["id"] for j in studio.get("/api/evals").json())

    rolled = studio.post(f"/api/evals/{job['id']}/rollout", {"row": 0})
    assert rolled.status_code == 200, rolled.text
    try:
        info = rolled.json()["rollout"]
        assert info["checkpoint"].endswith("deepmimic_humanoid_demo_model.pt")
        assert info["env_config"] == str(folder / "row0_env_config.yaml")
        assert "humanoid_demo_squat.pkl" in (folder / "row0_env_config.yaml").read_text()
    finally:
        studio.post("/api/scene/rollout/close")
    assert studio.post(f"/api/evals/{job['id']}/rollout", {"row": 5}).status_code == 422


def test_a_failing_eval_says_why(studio: StudioProcess) -> None:
    arg_file = write_arg_file(studio.runs_dir, "not_for_eval")  # the fake trainer's keys: no env config
    r = studio.post("/api/evals", {"checkpoint": SHIPPED, "arg_file": str(arg_file), "episodes": 1})
    assert r.status_code == 201, r.text
    done = finished(studio, r.json()["id"], 120)
    assert done["status"] == "failed" and done["rows"] == []
    assert done["error"].startswith("mimickit eval failed (exit code") and "\n" not in done["error"]
    assert studio.post(f"/api/evals/{done['id']}/rollout", {"row": 0}).status_code == 409


def test_eval_requests_that_do_not_fit_are_refused(studio: StudioProcess) -> None:
    def start(body: dict) -> int:
        return studio.post("/api/evals", body).status_code

    assert start({"checkpoint": "/etc/passwd"}) == 403
    assert start({"checkpoint": "../../etc/passwd"}) == 403
    assert start({"checkpoint": SHIPPED, "motion_file": "/etc/passwd"}) == 403
    assert start({"checkpoint": SHIPPED, "arg_file": "/etc/passwd"}) == 403
    assert start({"checkpoint": SHIPPED, "run_id": 1}) == 422
    assert start({}) == 422
    assert start({"checkpoint": SHIPPED, "episodes": 0}) == 422
    r = studio.post("/api/evals", {"checkpoint": SHIPPED, "episode": 2})
    assert r.status_code == 422 and "did you mean 'episodes'" in r.json()["detail"]
    assert start({"run_id": 99999}) == 404
    assert studio.get("/api/evals/99999").status_code == 404
