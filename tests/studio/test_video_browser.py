"""Export MP4 from the page, in real Chromium: with the demo clip playing, the player bar's "Export
MP4" starts a real `mimickit video` job on the server, the stream's `videos` events show its progress,
and a download link appears that serves the MP4."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.studio.conftest import CHROMIUM, StudioProcess, write_arg_file
from tests.studio.test_page_browser import open_page

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(CHROMIUM is None, reason="no chromium on PATH (apt-get install chromium)"),
]


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[StudioProcess]:
    runs_dir = tmp_path_factory.mktemp("video_browser_runs")
    write_arg_file(runs_dir, "short")
    s = StudioProcess(runs_dir, None)  # the project's own data: the demo clip plays at start-up
    yield s
    s.stop()


def test_export_mp4_of_the_clip_gives_a_download_link(browser, server: StudioProcess) -> None:
    page = open_page(browser, server, 1280, 720)
    page.locator("#export-video").click()
    page.locator("#video-status").wait_for(state="visible")
    link = page.locator("#video-link")
    link.wait_for(timeout=240_000)  # a real render on a shared machine
    assert link.inner_text() == "humanoid_demo_squat.mp4"
    assert "ready" in page.locator("#video-status").inner_text()
    href = link.get_attribute("href")
    (job,) = server.get("/api/videos").json()
    assert job["status"] == "finished" and job["kind"] == "clip" and job["clip"].endswith("humanoid_demo_squat.pkl")
    assert href == job["download"]
    video = server.get(href)
    assert video.headers["content-type"] == "video/mp4" and video.content[4:8] == b"ftyp"
    assert len(video.content) == job["bytes"]
    assert not page.locator("#export-video").is_disabled()
    assert page.errors == []
    page.close()


def test_an_export_waiting_for_the_renderer_is_stopped_from_the_page(browser, server: StudioProcess) -> None:
    """With the renderer busy (a long export through the API), the page's export waits with a Stop button;
    Stop ends it (it never starts) and the page says so; the busy one is then stopped through the API."""
    clip = server.get("/api/scene/state").json()["clip"]
    body = {"clip": clip, "seconds": 60, "width": 1920, "height": 1080}
    busy = server.post("/api/videos", body).json()
    try:
        page = open_page(browser, server, 1280, 720)
        page.locator("#export-video").click()
        stop = page.locator("#video-stop")
        stop.wait_for()
        assert "waiting for the renderer" in page.locator("#video-status").inner_text()
        assert page.locator("#export-video").is_disabled()
        mine = max(j["id"] for j in server.get("/api/videos").json())
        assert mine == busy["id"] + 1 and server.get(f"/api/videos/{mine}").json()["status"] == "queued"
        stop.click()
        page.locator("#video-status", has_text="stopped").wait_for()
        assert stop.count() == 0 and not page.locator("#export-video").is_disabled()
        job = server.get(f"/api/videos/{mine}").json()
        assert job["status"] == "stopped" and job["started_at"] is None
        assert page.errors == []
        page.close()
    finally:
        assert server.post(f"/api/videos/{busy['id']}/stop", json={}).json()["status"] == "stopped"
