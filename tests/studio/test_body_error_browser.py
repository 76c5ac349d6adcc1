"""The rollout panel's per-body error bars in real Chromium (Playwright, the apt browser): a rollout of the
shipped demo model shows one bar per body of the character, with the errors of the frame the scene shows
(a history frame after a seek) in the colours of the scene's scale; closing the rollout hides them."""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest

from studio.scene import error_colour
from tests.studio.conftest import StudioProcess, wait_for

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install playwright)")

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(CHROMIUM is None, reason="no chromium on PATH (apt-get install chromium)"),
]
SHIPPED = "data/models/deepmimic_humanoid_demo_model.pt"
ACTION_TIMEOUT_MS = 90_000  # the scene's software WebGL shares the page's main thread


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[StudioProcess]:
    s = StudioProcess(tmp_path_factory.mktemp("body_error_browser_runs"), None)  # the project's own data only
    yield s
    s.stop()


@pytest.fixture(scope="module")
def page(server: StudioProcess):
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=["--no-sandbox", "--disable-gpu"])
        page = browser.new_page(viewport={"width": 1280, "height": 720})
        page.set_default_timeout(ACTION_TIMEOUT_MS)
        page.errors = []
        page.on("pageerror", lambda e: page.errors.append(str(e)))
        page.goto(server.url)
        wait_for(lambda: page.locator("#frame-label").inner_text() != "–", 60, "the scene state on the page")
        yield page
        browser.close()


def bars(page) -> list[dict]:
    return page.eval_on_selector_all(
        "#body-error .be-col",
        """cols => cols.map(c => ({body: c.dataset.body, error: Number(c.dataset.error),
            colour: getComputedStyle(c.querySelector('.be-fill')).backgroundColor}))""",
    )


def test_one_bar_per_body_for_the_frame_shown(page, server: StudioProcess, tmp_path: Path) -> None:
    r = server.post("/api/scene/load_rollout", {"checkpoint": SHIPPED})
    assert r.status_code == 200, r.text
    try:
        wait_for(lambda: server.get("/api/scene/state").json()["rollout"]["step"] >= 40, 60, "40 rollout steps")
        page.locator("#body-error").wait_for(state="visible", timeout=60_000)
        server.post("/api/scene/pause")
        shown = server.post("/api/scene/seek", {"frame": 10}).json()["rollout"]["body_error"]
        want = dict(zip(shown["bodies"], shown["errors_m"], strict=True))

        def showing_the_seeked_frame() -> bool:
            got = bars(page)
            return len(got) == len(want) and all(abs(b["error"] - want[b["body"]]) < 1e-6 for b in got)

        wait_for(showing_the_seeked_frame, 60, "the bars of the history frame shown")
        got = bars(page)
        assert [b["body"] for b in got] == shown["bodies"] and len(got) == 15  # one bar per body, model order
        for b in got:  # the colour of the body in the scene (the server's scale and formula)
            assert b["colour"] == "rgb({}, {}, {})".format(*error_colour(b["error"], shown["scale_m"])), b
        assert len({b["colour"] for b in got}) > 1
        # Taller bars for larger errors (clamped at the scale).
        height_js = "fs => fs.map(f => f.getBoundingClientRect().height)"
        heights = page.eval_on_selector_all("#body-error .be-fill", height_js)
        worst, best = max(range(15), key=lambda i: got[i]["error"]), min(range(15), key=lambda i: got[i]["error"])
        assert heights[worst] > heights[best]
        legend = page.locator("#body-error .be-legend").inner_text()
        assert f"{shown['scale_m']} m" in legend and "root-relative" in legend
        page.locator("#rollout-panel").screenshot(path=str(tmp_path / "body_error.png"))
    finally:
        server.post("/api/scene/rollout/close")
    page.locator("#body-error").wait_for(state="hidden", timeout=60_000)
    assert page.errors == []
