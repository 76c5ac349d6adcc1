"""Eval jobs through the real server: `mimickit eval --json` of a checkpoint as a subprocess in the
job's own folder, its table, a failure reported in one line, a rollout of one row's clip, the jobs
pushed by `GET /api/stream` (`evals`), stopping a queued or running job and deleting an ended one, and
requests that name files outside the allowed folders."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.studio.conftest import StudioProcess, shipped_style_model, wait_for, write_arg_file, write_demo_dataset
from tests.studio.test_stream import EventReader

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
    assert row["clip"] == "data/motions/humanoid_demo_squat.pkl" and row["episodes"] == 1
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


def test_a_models_arg_file_motion_file_is_what_the_studio_evaluates_and_rolls_out(studio: StudioProcess) -> None:
    """A model beside an arg file naming `--motion_file` (as data/models/ ships them): its eval, its
    rollout and its video job use that clip, not the env config's."""
    _, short = write_demo_dataset(studio.runs_dir / "clips")
    model = shipped_style_model(studio.runs_dir / "sidecar", "--motion_file", str(short))
    job = studio.post("/api/evals", {"checkpoint": str(model), "episodes": 1}).json()
    assert job["motion_file"] == str(short), job
    state = studio.post("/api/scene/load_rollout", {"checkpoint": str(model), "play": False})
    assert state.status_code == 200, state.text
    try:
        assert [Path(f) for f in state.json()["rollout"]["motion_files"]] == [short]
    finally:
        studio.post("/api/scene/rollout/close")
    video = studio.post("/api/videos", {"checkpoint": str(model), "seconds": 0.2, "width": 64, "height": 48})
    assert video.status_code == 201, video.text
    assert f"--motion_file {short}\n" in (Path(video.json()["folder"]) / "args.txt").read_text()
    done = finished(studio, job["id"])
    assert done["status"] == "finished", done["error"]
    assert [Path(r["clip"]) for r in done["rows"]] == [short]
    rendered = wait_for(
        lambda: (j := studio.get(f"/api/videos/{video.json()['id']}").json())["status"] in ("finished", "failed") and j,
        240,
        "the video to end",
    )
    assert rendered["status"] == "finished", rendered["error"]


def test_a_failing_eval_says_why(studio: StudioProcess) -> None:
    arg_file = write_arg_file(studio.runs_dir, "not_for_eval")  # the fake trainer's keys: no env config
    r = studio.post("/api/evals", {"checkpoint": SHIPPED, "arg_file": str(arg_file), "episodes": 1})
    assert r.status_code == 201, r.text
    done = finished(studio, r.json()["id"], 120)
    assert done["status"] == "failed" and done["rows"] == []
    assert done["error"].startswith("mimickit eval failed (exit code") and "\n" not in done["error"]
    assert studio.post(f"/api/evals/{done['id']}/rollout", {"row": 0}).status_code == 409


def processes_in(folder: Path) -> list[int]:
    """Pids of the processes whose working directory is `folder` (an eval runs in its job's folder)."""
    pids = []
    for proc in Path("/proc").iterdir():
        try:
            if proc.name.isdigit() and Path(proc / "cwd").resolve() == folder.resolve():
                pids.append(int(proc.name))
        except OSError:
            continue  # gone meanwhile, or not ours to read
    return pids


def job_in(jobs: object, job_id: int) -> dict | None:
    return next((j for j in jobs if j["id"] == job_id), None)  # type: ignore[union-attr]


def test_jobs_pushed_by_the_stream_stopped_and_deleted(studio: StudioProcess) -> None:
    stream = EventReader(studio, "?topics=evals")
    try:
        assert stream.next()[0] == "hello"
        stream.until(lambda n, d: n == "evals", what="the eval jobs at connect")
        quick = studio.post("/api/evals", {"checkpoint": SHIPPED, "episodes": 1}).json()
        waiting = studio.post("/api/evals", {"checkpoint": SHIPPED, "episodes": 1}).json()
        assert waiting["status"] == "queued"  # one job at a time: it waits for `quick`
        stopped = studio.post(f"/api/evals/{waiting['id']}/stop", json={})
        assert stopped.status_code == 200 and stopped.json()["status"] == "stopped"
        done = stream.until(
            lambda n, d: n == "evals" and (job_in(d, quick["id"]) or {}).get("status") == "finished",
            timeout=240,
            what="the first job finished",
        )
        assert job_in(done, quick["id"])["rows"][0]["clip"] == "data/motions/humanoid_demo_squat.pkl"
        never = job_in(done, waiting["id"])
        assert never["status"] == "stopped" and never["started_at"] is None and never["rows"] == []
        assert not (Path(waiting["folder"]) / "report.json").exists()  # it never ran

        # A long one: stopped while it runs, its process group killed.
        long = studio.post("/api/evals", {"checkpoint": SHIPPED, "episodes": 256}).json()
        stream.until(
            lambda n, d: n == "evals" and (job_in(d, long["id"]) or {}).get("status") == "running",
            timeout=120,
            what="the long job running",
        )
        folder = Path(long["folder"])
        wait_for(lambda: processes_in(folder), 60, "the eval process in its folder")
        assert studio.client.delete(f"/api/evals/{long['id']}").status_code == 409  # running: stop it first
        assert studio.post(f"/api/evals/{long['id']}/stop", json={}).json()["status"] == "stopped"
        wait_for(lambda: not processes_in(folder), 20, "the eval's processes gone")
        stream.until(lambda n, d: n == "evals" and job_in(d, long["id"])["status"] == "stopped", what="the stop pushed")
        again = studio.post(f"/api/evals/{long['id']}/stop", json={})
        assert again.status_code == 409 and "already ended (stopped)" in again.json()["detail"]
        assert studio.post(f"/api/evals/{long['id']}/rollout", {"row": 0}).status_code == 409

        # Ended jobs are deleted: gone from the list, the stream and the disk.
        for job in (long, waiting, quick):
            assert studio.client.delete(f"/api/evals/{job['id']}").status_code == 204
            assert not Path(job["folder"]).exists()
        gone = stream.until(
            lambda n, d: n == "evals" and all(job_in(d, j["id"]) is None for j in (long, waiting, quick)),
            what="the deleted jobs gone from the stream",
        )
        assert all(job_in(gone, j["id"]) is None for j in (long, waiting, quick))
        assert studio.get(f"/api/evals/{quick['id']}").status_code == 404
        assert studio.client.delete(f"/api/evals/{quick['id']}").status_code == 404
        nxt = studio.post("/api/evals", {"checkpoint": SHIPPED, "episodes": 1}).json()
        assert nxt["id"] > long["id"]  # a deleted job's id is not given again
        studio.post(f"/api/evals/{nxt['id']}/stop", json={})
    finally:
        stream.close()


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
