"""End to end in real Chromium (Playwright, the apt browser): open the dashboard, load humanoid_walk,
play, pause, step, scrub, launch and stop a run from the page, and roll out a checkpoint with its
ghost and reward-term plot, and inspect it. The server's scene state is the
judge of what the clicks did; screenshots of the embedded viser canvas check that the character is
drawn (not a blank canvas) and moves. Headless Chromium renders WebGL in software (~1 fps), hence
the waits before each screenshot.

Set STUDIO_UPDATE_SCREENSHOTS=1 to write the screenshots to docs/studio_dashboard.png and
docs/studio_rollout.png.
"""

from __future__ import annotations

import io
import os
import time
from pathlib import Path

import numpy as np
import pytest

from mimickit.util.paths import PROJECT_ROOT
from tests.studio.conftest import CHROMIUM, StudioProcess, new_page, wait_for

Image = pytest.importorskip("PIL.Image")

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(CHROMIUM is None, reason="no chromium on PATH (apt-get install chromium)"),
]
RENDER_WAIT_S = 3.0  # software WebGL draws about one frame a second
HIDE_TOAST = "[class*=Notification-root] { display: none !important; }"


@pytest.fixture(scope="module")
def page(studio: StudioProcess, browser):
    page = new_page(browser, None, 1280, 720)
    page.on("dialog", lambda d: d.accept())  # "Delete run …?" confirmations
    page.goto(studio.url)
    return page


def state(studio: StudioProcess) -> dict:
    return studio.get("/api/scene/state").json()


def scene_pixels(page) -> np.ndarray:
    png = page.locator("#scene").screenshot()
    return np.asarray(Image.open(io.BytesIO(png)).convert("L"), dtype=np.float32)


def test_clip_player_in_the_browser(page, studio: StudioProcess, test_data, tmp_path: Path) -> None:
    canvas = page.frame_locator("#scene").locator("canvas").first
    canvas.wait_for(timeout=30_000)
    page.fill("#filter", "humanoid_walk")
    page.get_by_text("humanoid_walk.pkl", exact=True).click()
    s = wait_for(lambda: (st := state(studio))["clip"] and st["clip"].endswith("humanoid_walk.pkl") and st)
    assert s["char"].endswith("humanoid/humanoid.xml")
    wait_for(lambda: state(studio)["playing"] and state(studio)["frame"] > 0, what="playback after loading")

    page.click("#play")  # pause
    wait_for(lambda: not state(studio)["playing"], what="pause")
    frame = state(studio)["frame"]
    page.click("#step")
    wait_for(lambda: state(studio)["frame"] == (frame + 1) % 125, what="step button")
    page.locator("body").press("Space")  # MimicKit's key: step one frame
    wait_for(lambda: state(studio)["frame"] == (frame + 2) % 125, what="Space key")
    page.locator("body").press("Enter")  # MimicKit's key: play/pause
    wait_for(lambda: state(studio)["playing"], what="Enter key plays")
    page.locator("body").press("Enter")
    wait_for(lambda: not state(studio)["playing"], what="Enter key pauses")

    page.locator("#timeline").fill("20")  # scrub
    wait_for(lambda: state(studio)["frame"] == 20, what="scrub to frame 20")
    at_20 = state(studio)["root_pos"]
    _close_viser_toast(page)
    time.sleep(RENDER_WAIT_S)
    first = scene_pixels(page)
    page.locator("#timeline").fill("80")
    wait_for(lambda: state(studio)["frame"] == 80, what="scrub to frame 80")
    # against frame 20, not the state at load time: under load that poll can land on frame 80 itself
    assert state(studio)["root_pos"] != at_20
    time.sleep(RENDER_WAIT_S)
    second = scene_pixels(page)

    assert first.std() > 10, "the scene canvas looks blank"
    changed = np.abs(first - second) > 12
    assert changed.mean() > 0.002, "the picture did not change between frames 20 and 80"


def test_launch_and_stop_a_run_from_the_page(page, studio: StudioProcess, tmp_path: Path) -> None:
    page.reload()
    page.wait_for_selector("#arg-file option[value$='long.txt']", state="attached")
    page.click("#launch-box summary")  # the form is folded away until asked for
    page.select_option("#arg-file", value=str(studio.runs_dir / "args" / "long.txt"))
    page.fill("#run-name", "from the page")
    page.click("#launch-button")
    run = wait_for(
        lambda: next((r for r in studio.get("/api/runs").json() if r["name"] == "from the page"), None),
        what="the launched run",
    )
    wait_for(lambda: studio.get(f"/api/runs/{run['id']}").json()["status"] == "running", what="running")
    item = page.locator(f"[data-run-id='{run['id']}']")
    item.locator(".status.running").wait_for(timeout=10_000)
    page.click("#launch-box summary")  # fold the form again: the curves move up
    # Live curves from the metrics stream (uPlot): both returns, falls, the two paper errors (one plot
    # per unit), each reward term, the losses.
    page.wait_for_selector("#curves [data-group=returns][data-series='2'] canvas", timeout=15_000)
    for group in ("falls", "pos_err", "vel_err"):
        page.wait_for_selector(f"#curves [data-group={group}][data-series='1']")
    page.wait_for_selector("#curves [data-group=rewards][data-series='2']")
    page.wait_for_selector("#curves [data-group=losses][data-series='2']")
    if state(studio)["clip"]:
        studio.post("/api/scene/play")  # a moving character in the picture
    _close_viser_toast(page)
    time.sleep(RENDER_WAIT_S)  # software WebGL repaints slowly: the closed notice must be painted away
    shot = PROJECT_ROOT / "docs" / "studio_dashboard.png"
    if os.environ.get("STUDIO_UPDATE_SCREENSHOTS") != "1":
        shot = tmp_path / "studio_dashboard.png"
    page.screenshot(path=str(shot))
    studio.post("/api/scene/pause")
    item.locator("button[data-action=stop]").click()
    wait_for(lambda: studio.get(f"/api/runs/{run['id']}").json()["status"] == "stopped", what="stopped")
    item.locator(".status.stopped").wait_for(timeout=10_000)
    page.locator(f"[data-run-id='{run['id']}'] button[data-action=delete]").click()
    wait_for(lambda: studio.get(f"/api/runs/{run['id']}").status_code == 404, what="deleted after confirm")
    # The page's own DELETE must have come back too: a reload while it is in flight (the next test's) aborts
    # it, the page alerts "Failed to fetch", and that alert, raised mid-navigation, blocks the reload.
    item.wait_for(state="detached")


def test_rollout_in_the_browser(page, studio: StudioProcess, demo_checkpoint: Path, tmp_path: Path) -> None:
    page.reload()
    # 60 s: in CI's two workers the software-rendered 3D view can hold the page's thread for seconds.
    page.wait_for_selector(f"#checkpoint option[value='{demo_checkpoint}']", state="attached", timeout=60_000)
    page.select_option("#checkpoint", value=str(demo_checkpoint))
    page.click("#rollout-button")
    s = wait_for(lambda: (st := state(studio))["mode"] == "rollout" and st, 30, "the rollout to load")
    assert s["rollout"]["checkpoint"] == str(demo_checkpoint)
    wait_for(lambda: state(studio)["rollout"]["step"] > 30, 15, "the rollout to step")
    page.locator("#rollout-panel").wait_for(state="visible")
    # The dashboard's plot (uPlot): the reward and the five reward terms, fed by the stream.
    page.wait_for_selector("#rollout-plot[data-series='6'] canvas", timeout=60_000)
    assert "episode" in page.locator("#rollout-label").inner_text()
    assert "no training record" in page.locator("#rollout-label").inner_text()  # a fresh agent's checkpoint
    wait_for(lambda: "× real time" in page.locator("#clip-label").inner_text(), 15, "the measured rate", page=page)

    page.select_option("#fit-target", value="env_config=data/envs/deepmimic_humanoid_env.yaml")
    page.click("#inspect-button")
    page.wait_for_selector("#inspect [data-fits=true]", timeout=30_000)
    text = page.locator("#inspect").inner_text()
    assert "agent PPO" in text and "observations 464 · actions 28" in text

    # Pause and step with the page's controls: they drive the rollout now.
    page.click("#play")
    wait_for(lambda: not state(studio)["playing"], what="pause")
    step = state(studio)["rollout"]["step"]
    page.click("#step")
    wait_for(lambda: state(studio)["rollout"]["step"] == step + 1, what="one simulated step")
    page.click("#play")
    wait_for(lambda: state(studio)["playing"], what="play again")

    _close_viser_toast(page)
    time.sleep(RENDER_WAIT_S)
    pixels = np.asarray(Image.open(io.BytesIO(page.locator("#scene").screenshot())).convert("RGB"), dtype=np.int32)
    r, g, b = pixels[..., 0], pixels[..., 1], pixels[..., 2]
    ghost = (g > r + 25) & (g > b + 10) & (g > 90)  # translucent green over the dark ground
    # The character, each body coloured by its tracking error: pale steel (none) to amber and red.
    warm = (r > b + 60) & (r > 120)
    pale = (r > 150) & (g > 150) & (b > 160)
    assert ghost.mean() > 0.001, "no ghost (reference character) in the picture"
    assert (warm | pale).mean() > 0.001, "no character in the picture"
    shot = PROJECT_ROOT / "docs" / "studio_rollout.png"
    if os.environ.get("STUDIO_UPDATE_SCREENSHOTS") != "1":
        shot = tmp_path / "studio_rollout.png"
    page.screenshot(path=str(shot))

    page.click("#rollout-close")
    wait_for(lambda: state(studio)["mode"] == "clip", what="back to clips")
    page.locator("#rollout-panel").wait_for(state="hidden")


def _close_viser_toast(page) -> None:
    """Hide viser's "Software WebGL rendering detected" notice: it covers part of the scene and says
    nothing about the studio (a style rule, since the notice may appear after any click closed it)."""
    page.locator("#scene").element_handle().content_frame().add_style_tag(content=HIDE_TOAST)
