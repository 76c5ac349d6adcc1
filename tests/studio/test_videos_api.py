"""MP4 export jobs through the real server: a real `mimickit video` of the project's demo clip and of
the shipped demo policy, each in its job's own folder, decoded frame by frame; the jobs pushed by
`GET /api/stream` (`videos`); requests that are refused in one line naming the key; and the time
limit, which kills a render's process group."""

from __future__ import annotations

from pathlib import Path

import imageio_ffmpeg
import numpy as np
import pytest

from mimickit.util.paths import PROJECT_DATA_DIR
from studio.jobs.videos import VideoJobs
from studio.settings import Settings
from tests.studio.conftest import StudioProcess, wait_for
from tests.studio.test_evals_api import processes_in
from tests.studio.test_stream import EventReader

pytestmark = pytest.mark.integration

DEMO_CLIP = PROJECT_DATA_DIR / "motions" / "humanoid_demo_squat.pkl"
DEMO_CHAR = PROJECT_DATA_DIR / "assets" / "humanoid" / "humanoid.xml"
SHIPPED = PROJECT_DATA_DIR / "models" / "deepmimic_humanoid_demo_model.pt"


def ended(studio: StudioProcess, job_id: int, timeout: float = 240.0) -> dict:
    return wait_for(
        lambda: (j := studio.get(f"/api/videos/{job_id}").json())["status"] in ("finished", "failed") and j,
        timeout,
        f"video {job_id} to end",
    )


def check_mp4(data: bytes, path: Path, frames: int, width: int, height: int) -> None:
    """An MP4 (ISO box `ftyp` first) that decodes to `frames` frames of width × height."""
    assert data[4:8] == b"ftyp", data[:16]
    path.write_bytes(data)
    decoded = imageio_ffmpeg.read_frames(str(path))
    meta = next(decoded)
    assert tuple(meta["size"]) == (width, height)
    images = [np.frombuffer(f, np.uint8).reshape(height, width, 3) for f in decoded]
    assert len(images) == frames
    assert images[-1].std() > 5  # a rendered scene, not a blank frame


def test_a_clip_video_of_the_demo_clip(studio: StudioProcess, tmp_path: Path) -> None:
    body = {"clip": str(DEMO_CLIP), "char": str(DEMO_CHAR), "seconds": 1, "width": 160, "height": 120}
    r = studio.post("/api/videos", body)
    assert r.status_code == 201, r.text
    job = r.json()
    assert job["kind"] == "clip" and job["status"] in ("queued", "running") and job["download"] is None
    folder = Path(job["folder"])
    assert folder.parent == studio.runs_dir / "videos"
    done = ended(studio, job["id"])
    assert done["status"] == "finished", done["error"]
    assert done["download"] == f"/api/videos/{job['id']}/file" and done["bytes"] > 1000
    assert (folder / "console.log").is_file()  # rendered in its own working folder
    video = studio.get(done["download"])
    assert video.status_code == 200 and video.headers["content-type"] == "video/mp4"
    assert len(video.content) == done["bytes"]
    check_mp4(video.content, tmp_path / "clip.mp4", 30, 160, 120)  # 1 s at the clip's 30 Hz control rate
    assert any(j["id"] == job["id"] for j in studio.get("/api/videos").json())
    # The routes every job kind shares: an ended job is removed with its folder.
    assert studio.client.delete(f"/api/videos/{job['id']}").status_code == 204
    assert not folder.exists() and studio.get(f"/api/videos/{job['id']}").status_code == 404
    assert all(j["id"] != job["id"] for j in studio.get("/api/videos").json())


def test_a_policy_video_of_the_shipped_model_pushed_by_the_stream(studio: StudioProcess, tmp_path: Path) -> None:
    stream = EventReader(studio, "?topics=videos")
    try:
        r = studio.post("/api/videos", {"checkpoint": str(SHIPPED), "seconds": 0.5, "width": 128, "height": 96})
        assert r.status_code == 201, r.text
        job = r.json()
        assert job["kind"] == "policy" and "--model_file" in job["command"]
        args = (Path(job["folder"]) / "args.txt").read_text()
        assert "--env_config " in args and "--agent_config " in args  # the configs named beside the model
        pushed = stream.until(
            lambda n, d: n == "videos" and any(j["id"] == job["id"] and j["status"] == "finished" for j in d),
            timeout=240,
            what="the finished job in a videos event",
        )
        done = next(j for j in pushed if j["id"] == job["id"])
    finally:
        stream.close()
    video = studio.get(done["download"])
    assert video.headers["content-type"] == "video/mp4"
    check_mp4(video.content, tmp_path / "policy.mp4", 15, 128, 96)


@pytest.mark.parametrize(
    ("body", "status", "says"),
    [
        ({"clip": str(DEMO_CLIP), "fps": 30}, 422, "unknown key 'fps'"),
        ({"clip": str(DEMO_CLIP), "width": 161}, 422, "width: must be even"),
        ({"clip": str(DEMO_CLIP), "seconds": 0}, 422, "seconds:"),
        ({"clip": str(DEMO_CLIP), "seconds": 600}, 422, "seconds:"),
        ({"clip": str(DEMO_CLIP), "height": 4000}, 422, "height:"),
        ({"seconds": 1}, 422, "give one of `clip`, `run_id` or `checkpoint`"),
        ({"clip": str(DEMO_CLIP), "checkpoint": str(SHIPPED)}, 422, "give one of"),
        ({"clip": str(DEMO_CLIP), "env_config": "data/envs/deepmimic_humanoid_env.yaml"}, 422, "`clip` takes `char`"),
        ({"checkpoint": str(SHIPPED), "char": str(DEMO_CHAR)}, 422, "`char` goes with `clip`"),
        ({"clip": "/etc/passwd"}, 403, "outside the data and runs folders"),
        ({"clip": "data/motions/no_such_clip.pkl"}, 404, "not found"),
        ({"run_id": 999999}, 404, "999999"),
    ],
)
def test_bad_requests_get_one_line(studio: StudioProcess, body: dict, status: int, says: str) -> None:
    r = studio.post("/api/videos", body)
    assert r.status_code == status, r.text
    detail = r.json()["detail"]
    assert isinstance(detail, str) and says in detail and "\n" not in detail


def test_unknown_jobs_and_unfinished_files(studio: StudioProcess) -> None:
    assert studio.get("/api/videos/999999").status_code == 404
    assert "no video job 999999" in studio.get("/api/videos/999999/file").json()["detail"]


def test_the_time_limit_kills_the_render(tmp_path: Path) -> None:
    jobs = VideoJobs(Settings(runs_dir=tmp_path).resolved(), time_limit_s=1.0)
    try:
        job = jobs.submit_clip(DEMO_CLIP, DEMO_CHAR, seconds=30, width=320, height=240)
        wait_for(lambda: jobs.get(job.id).status not in ("queued", "running"), 60, "the time limit")
        assert job.status == "failed" and "took longer than 1 s" in job.error
        assert not job.file.exists()
        assert processes_in(job.folder) == []  # the renderer's process group is gone
    finally:
        jobs.close()


def test_a_running_render_is_stopped(studio: StudioProcess) -> None:
    """`POST /api/videos/{id}/stop`: the renderer's process group is killed, the job ends as stopped."""
    body = {"clip": str(DEMO_CLIP), "char": str(DEMO_CHAR), "seconds": 60, "width": 1920, "height": 1080}
    job = studio.post("/api/videos", body).json()
    folder = Path(job["folder"])
    wait_for(lambda: studio.get(f"/api/videos/{job['id']}").json()["status"] == "running", 240, "the render running")
    wait_for(lambda: processes_in(folder), 60, "the renderer in its folder")
    r = studio.post(f"/api/videos/{job['id']}/stop", json={})
    assert r.status_code == 200 and r.json()["status"] == "stopped", r.text
    wait_for(lambda: not processes_in(folder), 20, "the renderer's processes gone")
    done = studio.get(f"/api/videos/{job['id']}").json()
    assert done["status"] == "stopped" and done["error"] is None and done["download"] is None
    assert studio.get(f"/api/videos/{job['id']}/file").status_code == 409
    again = studio.post(f"/api/videos/{job['id']}/stop", json={})
    assert again.status_code == 409 and "already ended (stopped)" in again.json()["detail"]
    assert studio.post("/api/videos/999999/stop", json={}).status_code == 404
