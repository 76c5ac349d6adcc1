"""Eval and video jobs outlive their server: each job's record in its folder lets the next server on the
same runs folder list it with the same id. A server stopped cleanly (SIGTERM) leaves its ended jobs as
they were; a job running when its server was killed (`kill -9`) is listed as failed with a line saying
the server stopped while it ran, and its processes are gone; a new job gets the next id."""

from __future__ import annotations

import signal
from pathlib import Path

import pytest

from mimickit.util.paths import PROJECT_DATA_DIR
from tests.studio.conftest import StudioProcess, wait_for
from tests.studio.test_evals_api import processes_in

pytestmark = pytest.mark.integration

SHIPPED = "data/models/deepmimic_humanoid_demo_model.pt"
DEMO_CLIP = PROJECT_DATA_DIR / "motions" / "humanoid_demo_squat.pkl"
DEMO_CHAR = PROJECT_DATA_DIR / "assets" / "humanoid" / "humanoid.xml"


def ended(server: StudioProcess, kind: str, job_id: int, timeout: float = 300.0) -> dict:
    return wait_for(
        lambda: (j := server.get(f"/api/{kind}/{job_id}").json())["status"] not in ("queued", "running") and j,
        timeout,
        f"{kind} job {job_id} to end",
    )


def sigterm(server: StudioProcess) -> None:
    """Stop the server as a service manager does, and wait for it to exit (uvicorn shuts down, then
    raises the signal again: the exit status says SIGTERM)."""
    server.client.close()
    server.proc.send_signal(signal.SIGTERM)
    assert server.proc.wait(60) == -signal.SIGTERM


def test_jobs_are_listed_again_after_a_restart(tmp_path: Path) -> None:
    first = StudioProcess(tmp_path, None)
    try:
        ev = first.post("/api/evals", {"checkpoint": SHIPPED, "episodes": 1}).json()
        body = {"clip": str(DEMO_CLIP), "char": str(DEMO_CHAR), "seconds": 0.5, "width": 64, "height": 48}
        vid = first.post("/api/videos", body).json()
        ev_done, vid_done = ended(first, "evals", ev["id"]), ended(first, "videos", vid["id"])
        assert ev_done["status"] == "finished", ev_done["error"]
        assert vid_done["status"] == "finished", vid_done["error"]
        mp4 = first.get(vid_done["download"]).content
    finally:
        sigterm(first)

    second = StudioProcess(tmp_path, None)
    try:
        assert second.get("/api/evals").json() == [ev_done]  # the same id, status, table and times
        assert second.get("/api/videos").json() == [vid_done]
        assert second.get(vid_done["download"]).content == mp4
        rolled = second.post(f"/api/evals/{ev['id']}/rollout", {"row": 0, "play": False})
        assert rolled.status_code == 200, rolled.text
        second.post("/api/scene/rollout/close")

        # A long eval, running when its server is killed.
        long = second.post("/api/evals", {"checkpoint": SHIPPED, "episodes": 256}).json()
        assert long["id"] == ev["id"] + 1
        folder = Path(long["folder"])
        wait_for(lambda: second.get(f"/api/evals/{long['id']}").json()["status"] == "running", 120, "it running")
        wait_for(lambda: processes_in(folder), 60, "the eval process in its folder")
    finally:
        second.kill9()

    third = StudioProcess(tmp_path, None)
    try:
        jobs = {j["id"]: j for j in third.get("/api/evals").json()}
        assert sorted(jobs) == [ev["id"], long["id"]] and jobs[ev["id"]] == ev_done
        died = jobs[long["id"]]
        assert died["status"] == "failed" and died["rows"] == []
        assert died["error"] == "the server stopped while the job ran; it did not finish"
        wait_for(lambda: not processes_in(folder), 30, "the dead server's eval processes gone")
        assert third.post(f"/api/evals/{long['id']}/stop", json={}).status_code == 409  # it has ended
        nxt = third.post("/api/evals", {"checkpoint": SHIPPED, "episodes": 1}).json()
        assert nxt["id"] == long["id"] + 1  # after the highest, never reused
        third.post(f"/api/evals/{nxt['id']}/stop", json={})
        # A deleted job's id is not given again by the next server either.
        assert third.client.delete(f"/api/evals/{nxt['id']}").status_code == 204
        assert [j["id"] for j in third.get("/api/videos").json()] == [vid["id"]]
    finally:
        third.stop()
    fourth = StudioProcess(tmp_path, None)
    try:
        again = fourth.post("/api/evals", {"checkpoint": SHIPPED, "episodes": 1}).json()
        assert again["id"] == nxt["id"] + 1
        fourth.post(f"/api/evals/{again['id']}/stop", json={})
        assert fourth.post("/api/videos", body).json()["id"] == vid["id"] + 1
    finally:
        fourth.stop()
