"""The dashboard as one control surface, in real Chromium (Playwright, the apt browser): at 1280×720 the
middle of the 3D view is viser's canvas (no panel over it) and the player bar and the runs panel fit
without wrapping or overflowing; Space steps after the timeline was dragged; `?` lists the shortcuts;
two runs ticked and compared draw two curves per metric (uPlot) and a table of what differs; under
800 px the layout stacks and the 3D view keeps its width.

STUDIO_UPDATE_SCREENSHOTS=1 writes docs/studio_compare.png and docs/studio_narrow.png.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from mimickit.util.paths import PROJECT_ROOT
from tests.studio.conftest import CHROMIUM, StudioProcess, new_page, wait_for, write_arg_file

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(CHROMIUM is None, reason="no chromium on PATH (apt-get install chromium)"),
]
HIDE_TOAST = "[class*=Notification-root] { display: none !important; }"  # viser's "software WebGL" notice


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[StudioProcess]:
    runs_dir = tmp_path_factory.mktemp("page_browser_runs")
    write_arg_file(runs_dir, "short", rows=12, period=0.05)
    s = StudioProcess(runs_dir, None)  # the project's own data: the demo clip plays at start-up
    yield s
    s.stop()


def open_page(browser, server: StudioProcess, width: int, height: int):
    page = new_page(browser, server.url, width, height)
    page.frame_locator("#scene").locator("canvas").first.wait_for(timeout=60_000)
    wait_for(lambda: page.locator("#frame-label").inner_text() != "–", 30, "the scene state on the page")
    return page


def scene_frame(page):
    return page.locator("#scene").element_handle().content_frame()


def state(server: StudioProcess) -> dict:
    return server.get("/api/scene/state").json()


def test_the_3d_view_is_not_covered_and_the_bars_fit(browser, server: StudioProcess) -> None:
    page = open_page(browser, server, 1280, 720)
    time.sleep(2.0)  # viser lays out its (minimised) panel after the canvas appears
    box = page.locator("#scene").bounding_box()
    assert box["width"] >= 500 and box["height"] >= 400, box
    hit = scene_frame(page).evaluate(
        "([x, y]) => document.elementFromPoint(x, y).tagName", [box["width"] / 2, box["height"] / 2]
    )
    assert hit == "CANVAS", f"the centre of the 3D view is a {hit}, not the canvas"
    # Nothing of the page lies over the iframe either.
    assert (
        page.evaluate(
            "([x, y]) => document.elementFromPoint(x, y).id",
            [box["x"] + box["width"] / 2, box["y"] + box["height"] / 2],
        )
        == "scene"
    )
    # The player bar: two rows that do not wrap (each row one control high).
    for row in page.locator("#player .bar").all():
        assert row.bounding_box()["height"] < 40, "a player bar row wrapped"
    # No select or panel sticks out of its column.
    runs = page.locator("#runs").bounding_box()
    for sel in ("#checkpoint", "#fit-target"):
        b = page.locator(sel).bounding_box()
        assert b["x"] + b["width"] <= runs["x"] + runs["width"] + 0.5, f"{sel} overflows the runs panel"
    assert page.evaluate("document.documentElement.scrollWidth <= innerWidth")
    assert page.errors == []
    page.close()


def settled_frame(server: StudioProcess):
    """A check for `wait_for`: the paused scene's frame once two reads 0.5 s apart agree."""

    def check() -> int | None:
        first = state(server)["frame"]
        time.sleep(0.5)
        return first if state(server)["frame"] == first else None

    return check


def test_space_steps_after_dragging_the_timeline(browser, server: StudioProcess) -> None:
    page = open_page(browser, server, 1280, 720)
    server.post("/api/scene/pause")
    slider = page.locator("#timeline").bounding_box()
    y = slider["y"] + slider["height"] / 2
    page.mouse.move(slider["x"] + slider["width"] * 0.2, y)
    page.mouse.down()
    page.mouse.move(slider["x"] + slider["width"] * 0.5, y, steps=5)
    page.mouse.up()
    assert page.evaluate("document.activeElement.id") == "timeline"  # the slider keeps the focus
    frame = wait_for(lambda: (f := state(server)["frame"]) > 5 and f, what="the drag to seek")
    frame = wait_for(settled_frame(server), what="the drag's last seek answered")
    page.keyboard.press(" ")
    wait_for(lambda: state(server)["frame"] == frame + 1, what="Space to step one frame after the drag")
    page.keyboard.press("Enter")
    wait_for(lambda: state(server)["playing"], what="Enter to play after the drag")
    page.keyboard.press("Enter")
    wait_for(lambda: not state(server)["playing"], what="Enter to pause")
    page.fill("#filter", "squat ")  # typing in a text field is typing, not a shortcut
    time.sleep(0.5)
    assert not state(server)["playing"] and page.locator("#filter").input_value() == "squat "
    page.close()


def test_quick_arrow_presses_each_move_one_frame(browser, server: StudioProcess) -> None:
    page = open_page(browser, server, 1280, 720)
    server.post("/api/scene/pause")
    server.post("/api/scene/seek", {"frame": 10})
    wait_for(lambda: page.locator("#timeline").input_value() == "10", what="the page to show frame 10", page=page)
    page.locator("#play").focus()
    for _ in range(10):  # faster than the server answers: each press counted from the frame the page knew
        page.keyboard.press("ArrowRight")
    for _ in range(4):
        page.keyboard.press("ArrowLeft")
    # A loaded machine's page may stall for seconds between its seeks (the 3D view shares its thread):
    # wait for the frame the presses make, then check that it stays.
    wait_for(lambda: state(server)["frame"] == 16, 60, lambda: f"frame 16, at {state(server)['frame']}", page=page)
    assert wait_for(settled_frame(server), what="the presses' last seek answered") == 16
    page.close()


def test_a_clip_nobody_watches_is_drawn_once_a_second_and_at_full_rate_once_a_page_shows_it(
    browser, tmp_path: Path
) -> None:
    quiet = StudioProcess(tmp_path, None)  # its startup clip plays; no page has opened it

    def updates_per_s(wait) -> float:
        first = quiet.get("/api/scene/state").json()
        wait(3.0)
        last = quiet.get("/api/scene/state").json()
        assert last["playing"] and last["time"] != first["time"]  # the clock runs either way
        return (last["updates"] - first["updates"]) / 3.0

    try:
        assert updates_per_s(time.sleep) <= 1.5  # was the clip's 30 fps: 5% of a core for nobody
        page = new_page(browser, quiet.url, 1280, 720)
        wait_for(lambda: page.locator("#frame-label").inner_text() != "–", 60, "the page", page=page)
        assert updates_per_s(lambda s: page.wait_for_timeout(s * 1000)) >= 5  # CI, loaded: 13.3 of 30
        page.close()
    finally:
        quiet.stop()


@pytest.mark.parametrize("size", [(1280, 720), (390, 844)])
def test_a_rollout_leaves_the_3d_view_half_the_window_and_every_control_on_screen(
    browser, server: StudioProcess, size: tuple[int, int]
) -> None:
    width, height = size
    page = open_page(browser, server, width, height)
    r = server.post("/api/scene/load_rollout", {"checkpoint": "data/models/deepmimic_humanoid_demo_model.pt"})
    assert r.status_code == 200, r.text
    try:
        page.locator("#body-error").wait_for(state="visible", timeout=60_000)
        scene = page.locator("#scene").bounding_box()
        assert scene["height"] >= height / 2 - 1, scene  # was 249 px of 720 beside the rollout's panel
        for button in ("#play", "#step", "#export-replay", "#export-video", "#rollout-close"):
            box = page.locator(button).bounding_box()
            assert box["x"] >= 0 and box["x"] + box["width"] <= width, (button, box)  # Export MP4 was cut off
    finally:
        server.post("/api/scene/rollout/close")
    page.close()


def test_question_mark_lists_every_shortcut(browser, server: StudioProcess) -> None:
    page = open_page(browser, server, 1280, 720)
    dialog = page.locator("#shortcuts")
    assert dialog.is_hidden()
    page.keyboard.press("?")
    dialog.wait_for(state="visible")
    text = dialog.inner_text()
    for key, what in (("Enter", "play / pause"), ("Space", "step one frame"), ("←", "previous"), ("?", "this list")):
        assert key in text and what in text, text
    page.keyboard.press("Escape")
    dialog.wait_for(state="hidden")
    page.click("#shortcuts-button")
    dialog.wait_for(state="visible")
    page.close()


def test_two_runs_compared_overlay_and_their_settings_differ(browser, server: StudioProcess, tmp_path: Path) -> None:
    ids = []
    for seed, envs in ((3, 2), (4, 4)):  # other env counts: other samples per iteration, two visible curves
        body = {"arg_file": "args/short.txt", "name": f"seed {seed}", "rand_seed": seed, "num_envs": envs}
        ids.append(server.post("/api/runs", body).json()["id"])
    for i in ids:
        wait_for(lambda i=i: server.get(f"/api/runs/{i}").json()["status"] == "finished", 30, f"run {i} to finish")
    page = open_page(browser, server, 1280, 720)
    assert page.locator("#compare-button").is_disabled()
    for i in ids:
        page.locator(f'[data-compare="{i}"]').check()
    page.click("#compare-button")
    plot = page.locator("#compare-plots [data-metric=train_return][data-series='2']")
    plot.wait_for(timeout=15_000)
    assert plot.locator("canvas").count() == 1
    assert f"#{ids[0]}" in plot.inner_text() and f"#{ids[1]}" in plot.inner_text()  # the legend names both runs
    diff = page.locator("#compare-diff table")
    diff.wait_for()
    seed_row = diff.locator("tr", has=page.locator("td", has_text="launch.rand_seed"))
    assert seed_row.locator("td").all_inner_texts()[1:] == ["3", "4"]
    envs_row = diff.locator("tr", has=page.locator("td", has_text="launch.num_envs"))
    assert envs_row.locator("td").all_inner_texts()[1:] == ["2", "4"]
    shot = tmp_path / "studio_compare.png"
    if os.environ.get("STUDIO_UPDATE_SCREENSHOTS") == "1":
        shot = PROJECT_ROOT / "docs" / "studio_compare.png"
    scene_frame(page).add_style_tag(content=HIDE_TOAST)
    page.screenshot(path=str(shot))
    # Smoothing and the x axis redraw the same two curves.
    page.locator("#x-axis").select_option("iteration")
    page.locator("#smoothing").fill("0.6")
    page.wait_for_selector("#compare-plots [data-metric=train_return][data-series='2']")
    assert "iteration" in page.locator("#compare-plots [data-metric=train_return]").inner_text()
    page.locator(f'[data-run-id="{ids[0]}"]').click()  # selecting one run: back to its own curves
    page.locator("#curves").wait_for(state="visible")
    assert page.locator("#compare").is_hidden()
    assert page.errors == []
    page.close()


def test_narrow_screen_stacks_with_a_visible_3d_view(browser, server: StudioProcess, tmp_path: Path) -> None:
    page = open_page(browser, server, 390, 844)
    box = page.locator("#scene").bounding_box()
    assert box["width"] >= 380 and box["height"] >= 200, box
    # viser's own panel turns into a bottom sheet at this width; the page hides it: the centre is the canvas.
    centre = [box["width"] / 2, box["height"] / 2]
    hit = lambda: scene_frame(page).evaluate("([x, y]) => document.elementFromPoint(x, y).tagName", centre)  # noqa: E731
    wait_for(lambda: hit() == "CANVAS", 60, "the canvas at the centre of the 3D view (not viser's bottom sheet)")
    time.sleep(2.0)  # viser lays out its panel after the canvas appears: still the canvas after that
    assert hit() == "CANVAS", f"the centre of the 3D view is a {hit()}, not the canvas"
    runs = page.locator("#runs").bounding_box()
    assert runs["y"] >= box["y"] + box["height"], "the runs panel is not below the 3D view"
    for button in page.locator("#player button").all():  # the rows wrap: every control on the screen
        b = button.bounding_box()
        assert b is None or b["x"] + b["width"] <= 390, f"{button.inner_text()} is cut off"
    assert page.evaluate("document.documentElement.scrollWidth <= innerWidth"), "the page scrolls sideways"
    shot = tmp_path / "studio_narrow.png"
    if os.environ.get("STUDIO_UPDATE_SCREENSHOTS") == "1":
        shot = PROJECT_ROOT / "docs" / "studio_narrow.png"
    scene_frame(page).add_style_tag(content=HIDE_TOAST)
    time.sleep(1.0)
    page.screenshot(path=str(shot))
    assert page.errors == []
    page.close()


def test_the_launch_form_is_built_from_the_launch_fields(browser, server: StudioProcess) -> None:
    """The form's inputs are those of GET /api/runs/fields (studio/runs/launch_fields.py), in its order,
    each with its help as its tooltip, and what is filled in is what the run is launched with."""
    fields = server.get("/api/runs/fields").json()
    page = open_page(browser, server, 1280, 720)
    short = server.runs_dir / "args" / "short.txt"
    page.wait_for_selector("#arg-file option[value$='short.txt']", state="attached")
    ids = page.eval_on_selector_all("#launch-fields select, #launch-fields input", "es => es.map((e) => e.id)")
    assert ids == [f["widget"]["id"] for f in fields]
    assert [page.locator(f"#{i}").get_attribute("title") for i in ids] == [f["help"] for f in fields]
    page.locator("#launch-box summary").click()
    page.locator("#arg-file").select_option(str(short))
    typed = {"run-name": "every box", "num-envs": "3", "max-samples": "96", "max-hours": "0.5", "rand-seed": "5"}
    for element_id, text in {**typed, "num-cpus": "2", "num-gpus": "0"}.items():
        page.locator(f"#{element_id}").fill(text)
    page.locator("#launch-button").click()
    run = wait_for(
        lambda: next((r for r in server.get("/api/runs").json() if r["name"] == "every box"), None), 30, "the run"
    )
    launched = {"num_envs": 3, "max_samples": 96, "max_hours": 0.5, "rand_seed": 5, "num_cpus": 2, "num_gpus": 0}
    assert run["config"] == {"arg_file": str(short), **launched}
    wait_for(lambda: server.get(f"/api/runs/{run['id']}").json()["status"] == "finished", 30, "the run to end")
    assert page.errors == []
    page.close()


def test_a_sweep_from_the_form_runs_one_per_value_and_compares_as_a_group(browser, server: StudioProcess) -> None:
    """The launch form's sweep field queues one run per value through POST /api/sweeps (the stand-in
    trainer here; tests/studio/test_ray_executor.py runs a sweep of real trainers on a Ray head); the runs
    carry their sweep in the list, and "Compare sweep" overlays exactly that sweep's runs."""
    before = {r["id"] for r in server.get("/api/runs").json()}
    page = open_page(browser, server, 1280, 720)
    page.wait_for_selector("#arg-file option[value$='short.txt']", state="attached")
    page.locator("#launch-box summary").click()
    page.locator("#arg-file").select_option(str(server.runs_dir / "args" / "short.txt"))
    page.locator("#sweep-values").fill("rand_seed=7,8\nnum_envs=2")
    page.locator("#launch-button").click()
    wait_for(lambda: len({r["id"] for r in server.get("/api/runs").json()} - before) == 2, 30, "two sweep runs")
    new = [r for r in server.get("/api/runs").json() if r["id"] not in before]
    assert {r["config"]["rand_seed"] for r in new} == {7, 8} and {r["config"]["num_envs"] for r in new} == {2}
    (sweep,) = {r["sweep_id"] for r in new}
    assert sweep is not None
    for r in new:
        wait_for(lambda i=r["id"]: server.get(f"/api/runs/{i}").json()["status"] == "finished", 30, "the run to end")
    node = page.locator(f'[data-run-id="{new[0]["id"]}"]')
    assert f"sweep #{sweep}" in node.inner_text()
    node.locator('[data-action="compare sweep"]').click()
    page.locator("#compare-plots [data-metric=train_return][data-series='2']").wait_for(timeout=15_000)
    assert page.locator("#compare-button").inner_text() == "Compare 2"
    assert page.locator("#compare-plots [data-metric=train_return][data-series='3']").count() == 0
    # A line that is not key=values is one error line under the form, and nothing is queued.
    page.locator("#sweep-values").fill("rand_seed")
    page.locator("#launch-button").click()
    page.wait_for_function("document.querySelector('#launch-error').textContent.includes('key=value1,value2')")
    assert len(server.get("/api/runs").json()) == len(before) + 2
    assert page.errors == []
    page.close()


def held_commands(page, path: str) -> list:
    """The page's requests to `POST /api/scene/{path}`, held (not sent on) until the test continues them:
    what a server whose answer is slow (or queued behind the 3D view's frames) looks like to the page."""
    held: list = []
    page.route(f"**/api/scene/{path}", lambda route: held.append(route))
    return held


def test_play_pause_and_step_show_at_once_and_the_answer_settles_them(browser, server: StudioProcess) -> None:
    page = open_page(browser, server, 1280, 720)
    server.post("/api/scene/play")
    wait_for(lambda: page.locator("#play").inner_text() == "Pause", 60, "the page to show the clip playing", page)
    toggles = held_commands(page, "toggle")
    page.click("#play")
    wait_for(lambda: toggles, 60, "the click's toggle request", page)
    # The server has not answered (nor heard of it): the page shows the pause already.
    assert page.locator("#play").inner_text() == "Play" and state(server)["playing"]
    time.sleep(0.5)  # stream states of the still playing clip keep arriving: they must not flip it back
    assert page.locator("#play").inner_text() == "Play"
    toggles[0].continue_()
    wait_for(lambda: not state(server)["playing"], 60, "the held pause to reach the server", page)
    frame = wait_for(settled_frame(server), what="the paused frame")
    steps = held_commands(page, "step")
    page.click("#step")
    wait_for(lambda: steps, 60, "the click's step request", page)
    n = state(server)["num_frames"]
    assert page.locator("#frame-label").inner_text().startswith(f"{(frame + 1) % n}/{n - 1} ")
    assert state(server)["frame"] == frame
    steps[0].continue_()
    wait_for(lambda: state(server)["frame"] == (frame + 1) % n, 60, "the held step to reach the server", page)
    assert page.locator("#frame-label").inner_text().startswith(f"{(frame + 1) % n}/")
    page.close()


def test_a_refused_command_puts_the_controls_back(browser, server: StudioProcess) -> None:
    page = open_page(browser, server, 1280, 720)
    server.post("/api/scene/pause")
    wait_for(lambda: page.locator("#play").inner_text() == "Play", 60, "the page to show the clip paused", page)
    refused = '{"detail": "the scene is busy"}'
    page.route("**/api/scene/toggle", lambda route: route.fulfill(status=503, body=refused))
    page.click("#play")
    wait_for(lambda: "toggle: the scene is busy" in page.locator("#clip-label").inner_text(), 60, "the refusal", page)
    assert page.locator("#play").inner_text() == "Play" and not state(server)["playing"]
    page.close()


def test_the_3d_view_resolution_is_asked_of_viser_and_its_frame_rate_shown(browser, server: StudioProcess) -> None:
    page = open_page(browser, server, 1280, 720)
    server.post("/api/scene/play")
    software = page.evaluate("() => import('/web/scene_view.js').then((m) => m.isSoftwareGl())")
    auto = "fixedDpr=0.5" if software else None  # CI's Chromium draws WebGL on the CPU (SwiftShader)
    src = page.locator("#scene").get_attribute("src")
    assert (auto in src) if auto else ("fixedDpr" not in src), src
    fps = lambda: int(page.locator("#scene-fps").inner_text().split()[1])  # noqa: E731  "3D 12 fps"
    wait_for(lambda: fps() > 0, 60, "the 3D view's frame rate while the clip plays", page)
    page.select_option("#scene-quality", "quarter")
    wait_for(lambda: "fixedDpr=0.25" in page.locator("#scene").get_attribute("src"), 60, "the quarter view", page)
    page.frame_locator("#scene").locator("canvas").first.wait_for(timeout=60_000)
    wait_for(lambda: fps() > 0, 60, "the quarter view drawing", page)
    page.reload()  # the choice is the browser's: kept over a reload
    wait_for(lambda: "fixedDpr=0.25" in (page.locator("#scene").get_attribute("src") or ""), 60, "kept", page)
    assert page.locator("#scene-quality").input_value() == "quarter"
    page.evaluate("localStorage.removeItem('studio-scene-quality')")
    page.close()
