"""Curves a researcher works with, in real Chromium: a metric picked off and on, a pinned metric's plot
first (in the run's curves and in Compare), a log y axis (values ≤ 0 left out and counted), the choices
kept over a reload (localStorage), two runs compared with the cursor read on every plot at once, the
metrics downloaded as CSV, and a run tagged, then the list filtered by the tag while it updates.

STUDIO_UPDATE_SCREENSHOTS=1 writes docs/studio_curves.png.
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Iterator
from pathlib import Path

import pytest

from mimickit.util.paths import PROJECT_ROOT
from tests.studio.conftest import CHROMIUM, StudioProcess, new_page, wait_for, write_arg_file

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(CHROMIUM is None, reason="no chromium on PATH (apt-get install chromium)"),
]
WAIT_MS = 60_000
HIDE_TOAST = "[class*=Notification-root] { display: none !important; }"  # viser's "software WebGL" notice
ROWS = 12


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[StudioProcess]:
    runs_dir = tmp_path_factory.mktemp("curves_browser_runs")
    write_arg_file(runs_dir, "short", rows=ROWS, period=0.05)
    s = StudioProcess(runs_dir, None)
    yield s
    s.stop()


def finished_runs(server: StudioProcess) -> list[int]:
    ids = []
    for envs in (2, 4):  # other samples per iteration: the runs' rows lie at different x
        body = {"arg_file": "args/short.txt", "name": f"envs {envs}", "num_envs": envs}
        ids.append(server.post("/api/runs", body).json()["id"])
    for i in ids:
        wait_for(lambda i=i: server.get(f"/api/runs/{i}").json()["status"] == "finished", 60, f"run {i} to finish")
    return ids


def first_plot(page, box: str) -> str:
    plot = page.locator(f"{box} > .plot:not([hidden])").first
    return plot.get_attribute("data-group") or plot.get_attribute("data-metric")


def pick(page, metric: str) -> None:
    """The picker open and filtered down to `metric`."""
    if page.locator("#metric-picker").get_attribute("open") is None:
        page.click("#metric-picker summary")
    page.fill("#metric-filter", metric)
    page.locator(f'[data-metric-toggle="{metric}"]').wait_for(timeout=WAIT_MS)


def downloaded(page, click: str) -> str:
    with page.expect_download(timeout=WAIT_MS) as info:
        page.click(click)
    return Path(info.value.path()).read_text()


def test_pick_pin_log_compare_hover_csv_and_tags(browser, server: StudioProcess, tmp_path: Path) -> None:
    ids = finished_runs(server)
    page = new_page(browser, server.url)
    page.locator(f'[data-run-id="{ids[0]}"]').click()
    page.locator("#curves [data-group=returns][data-series='2']").wait_for(timeout=WAIT_MS)

    # A metric off and on again.
    pick(page, "train_return")
    page.locator('[data-metric-toggle="train_return"]').uncheck()
    page.locator("#curves [data-group=returns][data-series='1']").wait_for(timeout=WAIT_MS)
    page.locator('[data-metric-toggle="train_return"]').check()
    page.locator("#curves [data-group=returns][data-series='2']").wait_for(timeout=WAIT_MS)

    # A pinned metric's plot comes first; a log axis on it.
    pick(page, "critic_loss")
    page.click('[data-metric-pin="critic_loss"]')
    wait_for(lambda: first_plot(page, "#curves") == "losses", 60, "the pinned plot first", page)
    page.click("#curves [data-group=losses] .plot-log")
    losses = page.locator("#curves [data-group=losses][data-log=true]")
    losses.wait_for(timeout=WAIT_MS)
    lo, hi = (float(v) for v in losses.get_attribute("data-y-range").split(","))
    assert 0 < lo < hi and math.log10(lo).is_integer() and math.log10(hi).is_integer(), (lo, hi)

    # The choices are kept in the browser.
    page.reload()
    page.locator(f'[data-run-id="{ids[0]}"]').click()
    page.locator("#curves [data-group=losses][data-log=true][data-series='2']").wait_for(timeout=WAIT_MS)
    assert first_plot(page, "#curves") == "losses"

    # The selected run's metrics as CSV: its metrics.jsonl's rows.
    rows = [
        json.loads(line)
        for line in (Path(server.get(f"/api/runs/{ids[0]}").json()["out_dir"]) / "metrics.jsonl")
        .read_text()
        .splitlines()
    ]
    text = downloaded(page, "#csv-button")
    assert (
        text.splitlines()[0] == ",".join(dict.fromkeys(k for r in rows for k in r))
        and len(text.splitlines()) == ROWS + 1
    )

    compare_and_hover(page, ids, tmp_path)
    tag_and_filter(page, server, ids)
    assert page.errors == []
    page.close()


def compare_and_hover(page, ids: list[int], tmp_path: Path) -> None:
    """Two runs compared: the pinned metric first, log where chosen for its unit (a value ≤ 0 left out
    and said), and a hover on one plot reads both runs' values on every plot."""

    def negative_first_loss(route) -> None:  # one row's actor_loss ≤ 0, as a bad run could write
        rows = route.fetch().json()
        rows[0]["actor_loss"] = -1.0
        route.fulfill(json=rows)

    page.route(f"**/api/runs/{ids[0]}/metrics", negative_first_loss)
    for i in ids:
        page.locator(f'[data-compare="{i}"]').check()
    page.click("#compare-button")
    plot = page.locator("#compare-plots [data-metric=train_return][data-series='2']")
    plot.wait_for(timeout=WAIT_MS)
    assert first_plot(page, "#compare-plots") == "critic_loss"
    actor = page.locator("#compare-plots [data-metric=actor_loss][data-log=true][data-dropped='1']")
    actor.wait_for(timeout=WAIT_MS)
    assert "1 values ≤ 0 not drawn" in actor.locator(".plot-note").inner_text()
    over = plot.locator(".u-over")
    box = over.bounding_box()
    over.hover(position={"x": box["width"] * 0.6, "y": box["height"] / 2})
    for metric, step in (("train_return", 10), ("train_episode_length", 1)):  # the hovered plot and a synced one
        values = page.locator(f"#compare-plots [data-metric={metric}] .u-legend .u-series .u-value")
        wait_for(
            lambda v=values: all(re.fullmatch(r"\d+", t) for t in v.all_inner_texts()[1:]),
            60,
            f"{metric}'s values",
            page,
        )
        texts = values.all_inner_texts()
        assert len(texts) == 3 and all(int(t) % step == 0 for t in texts[1:]), texts
    shot = tmp_path / "studio_curves.png"
    if os.environ.get("STUDIO_UPDATE_SCREENSHOTS") == "1":
        shot = PROJECT_ROOT / "docs" / "studio_curves.png"
    page.locator("#scene").content_frame.locator("body").evaluate(
        "(b, css) => b.append(Object.assign(document.createElement('style'), {textContent: css}))", HIDE_TOAST
    )
    page.evaluate("document.querySelector('#curves-box').scrollIntoView({block: 'start'})")
    first = page.locator("#compare-plots > .plot").first.locator(".u-over")
    first.hover(position={"x": first.bounding_box()["width"] * 0.6, "y": 20})
    page.screenshot(path=str(shot))
    text = downloaded(page, "#csv-button")
    assert text.startswith("run,") and {line.split(",")[0] for line in text.splitlines()[1:]} == {str(i) for i in ids}
    page.unroute(f"**/api/runs/{ids[0]}/metrics")


def tag_and_filter(page, server: StudioProcess, ids: list[int]) -> None:
    """A run tagged from its entry, the list filtered by the tag, and the filter kept while runs come."""
    node = page.locator(f'[data-run-id="{ids[1]}"]')
    node.locator('[data-action="tags"]').click()
    node.locator('[data-field="tags-input"]').fill("baseline, fast")
    node.locator('[data-field="notes-input"]').fill("four envs")
    node.locator('[data-action="save-labels"]').click()
    node.locator(".chip", has_text="baseline").wait_for(timeout=WAIT_MS)
    assert server.get(f"/api/runs/{ids[1]}").json()["tags"] == ["baseline", "fast"]
    assert node.locator('[data-field="notes"]').get_attribute("title") == "four envs"
    page.fill("#run-filter", "baseline")
    page.locator(f'[data-run-id="{ids[0]}"]').wait_for(state="hidden", timeout=WAIT_MS)
    assert node.is_visible()
    new = server.post("/api/runs", {"arg_file": "args/short.txt", "name": "later"}).json()["id"]
    page.locator(f'[data-run-id="{new}"]').wait_for(state="attached", timeout=WAIT_MS)
    wait_for(lambda: server.get(f"/api/runs/{new}").json()["status"] == "finished", 60, "the later run", page)
    assert page.locator(f'[data-run-id="{new}"]').is_hidden() and node.is_visible()
    assert page.locator("#run-filter-count").inner_text() == "1 of 3"
