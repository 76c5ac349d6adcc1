"""The rollout panel's per-body error bars in real Chromium (Playwright, the apt browser): a rollout of the
shipped demo model shows one bar per body of the character, with the errors of the frame the scene shows
(a history frame after a seek) in the colours of the scene's scale; closing the rollout hides them. An AMP
rollout, whose policy follows the clip's style and not its ghost, shows none, and its reward plot takes in
its style reward (above 1)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from mimickit.util.paths import PROJECT_DATA_DIR
from studio.scene.view import error_colour
from tests.studio.conftest import CHROMIUM, StudioProcess, scene_page, wait_for, write_checkpoint_dir

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(CHROMIUM is None, reason="no chromium on PATH (apt-get install chromium)"),
]
SHIPPED = "data/models/deepmimic_humanoid_demo_model.pt"


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[StudioProcess]:
    s = StudioProcess(tmp_path_factory.mktemp("body_error_browser_runs"), None)  # the project's own data only
    yield s
    s.stop()


@pytest.fixture(scope="module")
def page(server: StudioProcess, browser):
    return scene_page(browser, server.url, 1280, 720)


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


def test_an_amp_rollout_plots_its_style_reward_and_shows_no_tracking_error(
    page, server: StudioProcess, tmp_path: Path
) -> None:
    # An untrained discriminator's reward is -log(1 - sigmoid(D)) * scale with D near 0: 0.9-2.4 at the
    # project's scale 2 (its random start decides); at scale 10 it is well above 1 whatever the start.
    agent = (PROJECT_DATA_DIR / "agents" / "amp_humanoid_agent.yaml").read_text()
    assert "disc_reward_scale: 2\n" in agent
    (tmp_path / "agent.yaml").write_text(agent.replace("disc_reward_scale: 2\n", "disc_reward_scale: 10\n"))
    amp = write_checkpoint_dir(
        server.runs_dir / "amp-fresh",
        (PROJECT_DATA_DIR / "envs" / "amp_humanoid_env.yaml").read_text(),
        agent_yaml=tmp_path / "agent.yaml",
    )
    r = server.post("/api/scene/load_rollout", {"checkpoint": str(amp)})
    assert r.status_code == 200, r.text
    try:
        s = wait_for(lambda: (s := server.get("/api/scene/state").json())["rollout"]["step"] >= 20 and s, 60, "steps")
        assert s["rollout"]["body_error"] is None, s["rollout"]["body_error"]
        rows = server.get("/api/scene/rollout/history").json()["rows"]
        disc = max(row["terms"]["disc"] for row in rows)
        assert disc > 1, rows
        plot = page.locator("#rollout-plot")

        def y_top() -> float | None:
            v = plot.get_attribute("data-y-range")  # "null,null" while the plot has no data
            return float(v.split(",")[1]) if v and "null" not in v else None

        seen = lambda: f"the plot's y axis to take in the style reward (up to {disc:.2f}): top {y_top()}"  # noqa: E731
        wait_for(lambda: (top := y_top()) is not None and top > 1, 60, seen, page=page)
        assert page.locator("#body-error").is_hidden()
    finally:
        server.post("/api/scene/rollout/close")


def test_a_rollout_scrubbed_back_past_the_plot_window_keeps_its_cursor_in_view(page, server: StudioProcess) -> None:
    r = server.post("/api/scene/load_rollout", {"checkpoint": SHIPPED, "play": False})
    assert r.status_code == 200, r.text
    try:
        server.post("/api/scene/step", {"frames": 300})
        end = server.post("/api/scene/step", {"frames": 150}).json()["time"]  # 15 s recorded
        plot = page.locator("#rollout-plot")

        def x_range() -> tuple[float, float] | None:
            v = plot.get_attribute("data-x-range")  # "null,null" while the plot has no data
            return tuple(map(float, v.split(","))) if v and "null" not in v else None

        wait_for(lambda: (x := x_range()) and x[1] >= end - 0.1, 60, "the plot at the live end", page=page)
        shown = server.post("/api/scene/seek", {"frame": 30}).json()["time"]  # 1 s in: 14 s back
        wait_for(lambda: (x := x_range()) and x[0] <= shown <= x[1], 60, "the plot around the cursor", page=page)
    finally:
        server.post("/api/scene/rollout/close")
