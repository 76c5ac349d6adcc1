"""A sweep from the page's launch form, in real Chromium: `devices=cpu cpu` is sent as one value of two
devices (a list, each its own trainer argument), and a run's "Stop sweep" stops every run of its sweep in
one request (the queued ones never start)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.studio.conftest import CHROMIUM, StudioProcess, wait_for, write_arg_file
from tests.studio.test_page_browser import open_page

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(CHROMIUM is None, reason="no chromium on PATH (apt-get install chromium)"),
]


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[StudioProcess]:
    runs_dir = tmp_path_factory.mktemp("sweep_browser_runs")
    write_arg_file(runs_dir, "long", rows=400, period=0.2)
    s = StudioProcess(runs_dir, None)
    yield s
    s.stop()


def test_stop_sweep_stops_every_run_of_the_sweep(browser, server: StudioProcess) -> None:
    page = open_page(browser, server, 1280, 720)
    page.wait_for_selector("#arg-file option[value$='long.txt']", state="attached")
    page.locator("#launch-box summary").click()
    page.locator("#arg-file").select_option(str(server.runs_dir / "args" / "long.txt"))
    page.locator("#sweep-values").fill("rand_seed=1,2,3\ndevices=cpu cpu")
    page.locator("#launch-button").click()
    wait_for(lambda: len(server.get("/api/runs").json()) == 3, 30, "three sweep runs")
    runs = server.get("/api/runs").json()
    assert [r["config"]["args"] for r in runs] == [{"devices": ["cpu", "cpu"]}] * 3
    first = runs[0]["id"]
    wait_for(lambda: server.get(f"/api/runs/{first}").json()["status"] == "running", 30, "the first run to start")
    page.locator(f'[data-run-id="{runs[-1]["id"]}"] [data-action="stop sweep"]').click()
    ended = lambda: {server.get(f"/api/runs/{r['id']}").json()["status"] for r in runs} == {"stopped"}  # noqa: E731
    wait_for(ended, 60, "every run of the sweep to stop")
    assert [server.get(f"/api/runs/{r['id']}").json()["attempts"] for r in runs] == [1, 0, 0]
    assert page.errors == []
    page.close()
