"""The Analysis box in real Chromium: opened, it plots the clip's joint angles and velocities, its root
path and foot contacts; its cursor follows the player; a click on a plot seeks the player; a rollout's
curves come as the character's and its reference's series. Nothing is fetched while it is closed.

STUDIO_UPDATE_SCREENSHOTS=1 writes docs/studio_analysis.png (1280×720).
"""

from __future__ import annotations

import os
from collections.abc import Iterator

import pytest

from mimickit.util.paths import PROJECT_ROOT
from tests.studio.conftest import CHROMIUM, StudioProcess, scene_page, wait_for

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(CHROMIUM is None, reason="no chromium on PATH (apt-get install chromium)"),
]
WAIT_S = 90
HIDE_TOAST = "[class*=Notification-root] { display: none !important; }"  # viser's "software WebGL" notice


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[StudioProcess]:
    s = StudioProcess(tmp_path_factory.mktemp("analysis_browser_runs"), None)  # the demo clip plays at start-up
    yield s
    s.stop()


def data(page, selector: str, key: str) -> str | None:
    return page.locator(selector).evaluate(f"e => e.dataset.{key} ?? null")


def test_the_analysis_box_plots_follows_and_seeks(browser, server: StudioProcess) -> None:
    requests: list[str] = []
    page = scene_page(browser, server.url, wait_s=WAIT_S)
    page.on("request", lambda r: requests.append(r.url) if "/api/scene/analysis" in r.url else None)
    state = server.post("/api/scene/seek", {"frame": 10}).json()
    server.post("/api/scene/pause")
    n, fps = state["num_frames"], state["fps"]
    page.wait_for_timeout(500)  # a scene state or two reach the page: still nothing fetched while closed
    assert requests == []

    page.locator("#analysis-box > summary").click()
    wait_for(lambda: data(page, "#analysis-angle", "series") == "4", WAIT_S, "four hinges' angles", page)
    assert data(page, "#analysis-velocity", "series") == "4" and data(page, "#analysis-height", "series") == "1"
    assert data(page, "#analysis-path", "points") == str(n) and data(page, "#analysis-contacts", "lanes") == "2"
    assert page.locator("#analysis-joints input:checked").count() == 4

    # The cursor follows the player (a seek from elsewhere, here the API).
    server.post("/api/scene/seek", {"frame": 60})
    wait_for(
        lambda: abs(float(data(page, "#analysis-angle", "cursor") or -1) - 60 / fps) < 1e-3,
        WAIT_S,
        "the cursor at frame 60",
        page,
    )

    # A click on a plot seeks the player there: a quarter of the way along the clip.
    over = page.locator("#analysis-angle .u-over")
    box = over.bounding_box()
    over.click(position={"x": box["width"] * 0.25, "y": box["height"] / 2})
    want = round(0.25 * (n - 1))
    wait_for(
        lambda: abs(server.get("/api/scene/state").json()["frame"] - want) <= 2,
        WAIT_S,
        f"the player near frame {want}",
        page,
    )

    # Another joint picked: its curve is fetched and drawn.
    page.locator("#analysis-joints input[value=abdomen]").check()
    wait_for(lambda: data(page, "#analysis-angle", "series") == "5", WAIT_S, "five angles", page)
    assert page.errors == []


def test_a_rollout_plots_the_character_beside_its_reference(browser, server: StudioProcess) -> None:
    page = scene_page(browser, server.url, wait_s=WAIT_S)
    page.add_style_tag(content=HIDE_TOAST)
    page.locator("#analysis-box > summary").click()
    wait_for(lambda: data(page, "#analysis-angle", "series") == "4", WAIT_S, "the clip's curves", page)
    r = server.post("/api/scene/load_rollout", {"checkpoint": "data/models/deepmimic_humanoid_demo_model.pt"})
    assert r.status_code == 200, r.text
    try:
        # Four hinges, the character's and the reference's: eight series; two lanes per foot.
        wait_for(lambda: data(page, "#analysis-angle", "series") == "8", WAIT_S, "sim and ref series", page)
        wait_for(lambda: data(page, "#analysis-contacts", "lanes") == "4", WAIT_S, "sim and ref contacts", page)
        assert "reference dashed" in page.locator("#analysis-status").inner_text()
        # A live rollout is fetched again as it records (at most every 2 s): the curves grow.
        first = int(data(page, "#analysis-path", "points"))
        wait_for(lambda: int(data(page, "#analysis-path", "points")) > first, WAIT_S, "a refresh", page)
        if os.environ.get("STUDIO_UPDATE_SCREENSHOTS"):
            wait_for(lambda: server.get("/api/scene/state").json()["num_frames"] >= 150, WAIT_S, "5 s recorded")
            shown = server.post("/api/scene/seek", {"frame": 100}).json()  # pauses: the cursor mid-history
            wait_for(
                lambda: data(page, "#analysis-path", "points") == str(shown["num_frames"]),
                WAIT_S,
                "the paused history",
                page,
            )
            page.locator("#analysis-contacts").scroll_into_view_if_needed()
            page.screenshot(path=str(PROJECT_ROOT / "docs" / "studio_analysis.png"))
        assert page.errors == []
    finally:
        server.post("/api/scene/rollout/close")
