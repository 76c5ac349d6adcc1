"""The rollout panel's Push control in real Chromium (Playwright, the apt browser): load the shipped demo
model's rollout, pick a direction and a strength, press *Push*: the push is recorded (the state's last
push, the panel's status line) and the reward plot marks it; a shove that throws the character shows the
fall after it (status line, a second marker). A drag on a body in the 3D view pulls it toward the
pointer, and the other way when dragged back. No fixed sleeps: every check waits on its outcome.
STUDIO_UPDATE_SCREENSHOTS=1 writes the view with the push's arrow to docs/studio_push.png (1280×720)."""

from __future__ import annotations

import io
import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from mimickit.util.paths import PROJECT_ROOT
from tests.studio.conftest import CHROMIUM, StudioProcess, scene_page, wait_for
from tests.studio.test_e2e_browser import HIDE_TOAST, Image
from tests.studio.test_rollout_push import DEMO

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(CHROMIUM is None, reason="no chromium on PATH (apt-get install chromium)"),
]
WAIT_S = 90  # the scene's software WebGL shares the page's main thread


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[StudioProcess]:
    s = StudioProcess(tmp_path_factory.mktemp("push_browser_runs"), None)  # the project's own data only
    yield s
    s.stop()


@pytest.fixture(scope="module")
def page(server: StudioProcess, browser):
    return scene_page(browser, server.url, 1280, 720)


def markers(page) -> int:
    return int(page.locator("#rollout-plot").get_attribute("data-markers") or 0)


def arrow_share(page) -> float:
    """The share of the 3D view's pixels in the push arrow's cyan (studio/scene/view.py PUSH_COLOR)."""
    rgb = np.asarray(Image.open(io.BytesIO(page.locator("#scene").screenshot())).convert("RGB"), dtype=np.int32)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    return float(((b > 120) & (b - r > 60) & (g - r > 40)).mean())  # lit or shaded: bluer and greener than red


def test_push_from_the_panel_is_recorded_and_marked(page, server: StudioProcess, tmp_path: Path) -> None:
    r = server.post("/api/scene/load_rollout", DEMO)
    assert r.status_code == 200, r.text
    try:
        page.locator("#push-bar").wait_for(state="visible", timeout=WAIT_S * 1000)
        wait_for(lambda: page.locator("#push-body").input_value() == "pelvis", WAIT_S, "the body list")
        wait_for(lambda: server.get("/api/scene/state").json()["rollout"]["step"] >= 20, WAIT_S, "20 steps")
        page.select_option("#push-dir", "+y")
        page.locator("#push-force").fill("3000")
        assert page.locator("#push-force-label").inner_text() == "3000 N"
        page.click("#push-button")

        status = page.locator("#push-status")
        wait_for(lambda: status.get_attribute("data-pushed"), WAIT_S, "the push in the panel", page=page)
        assert status.inner_text().startswith("pushed pelvis 3000 N for 0.20 s")
        last = server.get("/api/scene/state").json()["rollout"]["push"]["last"]
        assert (last["body"], last["force"], last["steps"]) == ("pelvis", [0.0, 3000.0, 0.0], 6)
        wait_for(lambda: markers(page) >= 1, WAIT_S, "the push marker on the reward plot", page=page)
        # 3000 N sideways for 0.2 s throws the demo policy from most starts: a fall after the push, marked too.
        # From some starts it recovers (CI once waited 90 s for no fall): then a harder shove, pushed likewise.
        try:
            wait_for(lambda: status.get_attribute("data-fell"), WAIT_S / 3, "the fall after the push", page=page)
        except AssertionError:
            page.locator("#push-force").fill("5000")
            page.select_option("#push-duration", "0.5")
            page.click("#push-button")
            wait_for(lambda: status.get_attribute("data-fell"), WAIT_S, "the fall after a second push", page=page)
        assert " fell " in status.inner_text() and "after a push" in status.inner_text()
        wait_for(lambda: markers(page) >= 2, WAIT_S, "the fall marker on the reward plot", page=page)

        # The picture: paused on a frame the push acts on, its arrow drawn at the pelvis.
        server.post("/api/scene/pause")
        dt = 1.0 / 30.0
        shown = server.post("/api/scene/seek", {"time": (last["at_step"] + 2) * dt}).json()
        assert shown["rollout"]["push"]["acting"], shown["rollout"]["push"]
        shot = PROJECT_ROOT / "docs" / "studio_push.png"
        if os.environ.get("STUDIO_UPDATE_SCREENSHOTS") != "1":
            shot = tmp_path / "studio_push.png"
        page.locator("#scene").element_handle().content_frame().add_style_tag(content=HIDE_TOAST)
        wait_for(lambda: arrow_share(page) > 1e-4, WAIT_S, "the push's arrow in the 3D view", page=page)
        server.post("/api/scene/seek", {"time": (last["at_step"] + 8) * dt})  # after the push: no arrow
        wait_for(lambda: arrow_share(page) < 2e-5, WAIT_S, "the arrow gone after the push", page=page)
        server.post("/api/scene/seek", {"time": (last["at_step"] + 2) * dt})
        wait_for(lambda: arrow_share(page) > 1e-4, WAIT_S, "the arrow again", page=page)
        page.screenshot(path=str(shot))
    finally:
        server.post("/api/scene/rollout/close")
    page.locator("#rollout-panel").wait_for(state="hidden", timeout=WAIT_S * 1000)
    assert page.errors == []


def character_point(page) -> tuple[float, float] | None:
    """A page point on the character's body: of the 3D view's warm pixels (the bodies' sand, orange and
    red; not the ghost's green, the grid's grey-blue or the labels' white), the one nearest their middle;
    None before the character is drawn."""
    box = page.locator("#scene").bounding_box()
    rgb = np.asarray(Image.open(io.BytesIO(page.locator("#scene").screenshot())).convert("RGB"), dtype=np.int32)
    r, b = rgb[..., 0], rgb[..., 2]
    ys, xs = np.nonzero((r > 140) & (r - b > 50))
    if len(xs) < 50:
        return None
    i = int(np.argmin(np.hypot(xs - xs.mean(), ys - ys.mean())))
    sx, sy = box["width"] / rgb.shape[1], box["height"] / rgb.shape[0]
    return box["x"] + xs[i] * sx, box["y"] + ys[i] * sy


def drag(page, at: tuple[float, float], dx: float) -> None:
    """Press on `at`, move `dx` px sideways over about a second, release."""
    page.mouse.move(*at)
    page.mouse.down()
    page.mouse.move(at[0] + dx, at[1], steps=20)
    for _ in range(5):  # held: viser sends its drag updates (~20/s) while the pointer moves
        page.mouse.move(at[0] + dx, at[1] + 1, steps=2)
        page.mouse.move(at[0] + dx, at[1], steps=2)
    page.mouse.up()


def test_a_drag_on_a_body_pulls_it_toward_the_pointer(page, server: StudioProcess) -> None:
    r = server.post("/api/scene/load_rollout", {**DEMO, "play": False})  # paused: the figure holds still
    assert r.status_code == 200, r.text
    bodies = r.json()["rollout"]["push"]["bodies"]
    try:
        server.post("/api/scene/step", {"frames": 20})
        page.locator("#push-bar").wait_for(state="visible", timeout=WAIT_S * 1000)
        page.locator("#scene").element_handle().content_frame().add_style_tag(content=HIDE_TOAST)
        at = wait_for(lambda: character_point(page), WAIT_S, "the character drawn", page=page)

        def last() -> dict | None:
            return server.get("/api/scene/state").json()["rollout"]["push"]["last"]

        drag(page, at, 120)
        right = wait_for(last, WAIT_S, "a pull from the drag", page=page)
        assert right["body"] in bodies and right["steps"] == 3, right  # DRAG_PUSH_S: 0.1 s at 30 Hz
        f = np.asarray(right["force"])
        assert 1.0 < np.linalg.norm(f) <= 5000 and abs(f[2]) < np.linalg.norm(f[:2]), f  # a sideways drag
        assert page.locator("#push-body").input_value() == right["body"]  # the dragged body is picked

        drag(page, at, -120)  # the other way: the pull turns round
        wait_for(lambda: np.dot(last()["force"], f) < 0, WAIT_S, "the pull the other way", page=page)
    finally:
        server.post("/api/scene/rollout/close")
    page.locator("#rollout-panel").wait_for(state="hidden", timeout=WAIT_S * 1000)
    assert page.errors == []
