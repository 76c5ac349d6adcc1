"""The dashboard on its event stream, in real Chromium (Playwright, the apt browser): an idle page
makes no requests (the stream stays open and pushes), a focused run-list button keeps its focus while
its run trains, and when the server dies the page shows a banner, then reconnects by itself to a
server restarted on the same port: banner gone, controls working, the 3D scene's page reloaded and
connected again."""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator

import pytest

from tests.studio.conftest import CHROMIUM, StudioProcess, new_page, wait_for, write_arg_file

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(CHROMIUM is None, reason="no chromium on PATH (apt-get install chromium)"),
]
IDLE_S = 3.0
FRAMES_TIMEOUT_S = 60.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    """A studio on a fixed port, so that it can be killed and started again where the page expects it."""

    def __init__(self, runs_dir) -> None:
        self.runs_dir, self.port = runs_dir, free_port()
        self.proc = self.start()

    def start(self) -> StudioProcess:
        self.proc = StudioProcess(self.runs_dir, None, "--port", str(self.port))
        return self.proc


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    runs_dir = tmp_path_factory.mktemp("stream_browser_runs")
    write_arg_file(runs_dir, "long", rows=600, period=0.2)
    s = Server(runs_dir)
    yield s
    s.proc.stop()


@pytest.fixture(scope="module")
def page(server: Server, browser):
    page = new_page(browser, server.proc.url, 1500, 860)
    page.frame_locator("#scene").locator("canvas").first.wait_for(timeout=60_000)
    return page


def page_errors(page) -> list[str]:
    """Uncaught errors and rejections of the dashboard's scripts so far."""
    return page.errors


def frame_label(page) -> str:
    return page.locator("#frame-label").inner_text()


def test_an_idle_page_makes_no_requests(page, server: Server) -> None:
    wait_for(lambda: frame_label(page) != "–", what="the scene state pushed to the page")
    time.sleep(2.0)  # the scene page's own start-up fetches
    requests: list[str] = []

    def record(request) -> None:
        requests.append(request.url)

    page.on("request", record)
    # Watch for at least IDLE_S and until four frames have reached the page: a loaded machine's
    # software-rendered 3D view can hold the page's main thread for seconds, so the window is not fixed.
    labels = {frame_label(page)}
    start = time.monotonic()
    while time.monotonic() - start < IDLE_S or (len(labels) < 4 and time.monotonic() - start < FRAMES_TIMEOUT_S):
        labels.add(frame_label(page))
        time.sleep(0.2)
    assert requests == [], f"the idle page requested {requests}"
    assert len(labels) >= 4, f"the playing clip's frames did not reach the page in {FRAMES_TIMEOUT_S:.0f} s: {labels}"
    page.click("#step")  # the recorder does see requests: a user's action makes one
    wait_for(lambda: any(u.endswith("/api/scene/step") for u in requests), what="the step request recorded", page=page)
    page.remove_listener("request", record)
    assert page_errors(page) == []


def test_focus_on_a_run_button_survives_updates(page, server: Server) -> None:
    run = server.proc.post("/api/runs", {"arg_file": "args/long.txt", "name": "focus"}).json()
    stop = page.locator(f'[data-run-id="{run["id"]}"] [data-action="stop"]')
    samples = page.locator(f'[data-run-id="{run["id"]}"] [data-field="samples"]')
    wait_for(lambda: stop.is_enabled() and not samples.inner_text().startswith("–"), what="the run training")
    stop.focus()
    before = samples.inner_text()
    wait_for(lambda: samples.inner_text() != before, what="the run's progress reaching the page")
    assert stop.evaluate("b => b === document.activeElement && b.isConnected"), "the focused button lost focus"
    stop.click()  # a click on the updated list lands
    wait_for(
        lambda: server.proc.get(f"/api/runs/{run['id']}").json()["status"] in ("stopping", "stopped"),
        what="the stop clicked",
    )


def test_banner_while_the_server_is_gone_and_reconnect_after_restart(page, server: Server) -> None:
    frames: list[float] = []  # arrival times of the scene websocket's frames, whichever socket
    opened: list[float] = []  # when the scene's page opened (or tried to open) a websocket

    def watch(ws) -> None:
        if ws.url.split("?")[0].rstrip("/").endswith("/scene"):
            opened.append(time.monotonic())
            ws.on("framereceived", lambda _: frames.append(time.monotonic()))

    page.on("websocket", watch)
    banner = page.locator("#banner")
    assert banner.is_hidden()
    server.proc.kill9()
    killed = time.monotonic()
    banner.wait_for(state="visible", timeout=15_000)
    # viser's page, which does not have the focus (the dashboard has it), keeps trying to reconnect: a scene
    # whose one try failed would otherwise stay grey for good.
    wait_for(
        lambda: sum(t > killed for t in opened) >= 2,
        timeout=30,
        what=lambda: (
            f"the 3D scene's page retrying its websocket while the server is gone ({len(opened)} tries in all)"
        ),
        page=page,
    )
    assert "server unreachable" in banner.inner_text()
    time.sleep(1.0)
    assert banner.is_visible()  # still down: still said

    restarted = server.start()
    started = time.monotonic()
    banner.wait_for(state="hidden", timeout=60_000)
    # The page works again without a reload: a click drives the new server and its state comes back.
    page.click("#step")
    wait_for(lambda: restarted.get("/api/scene/state").json()["playing"] is False, what="Step pauses")
    frame = restarted.get("/api/scene/state").json()["frame"]
    wait_for(lambda: frame_label(page).startswith(f"{frame}/"), what=f"frame {frame} pushed to the page")
    # The 3D scene: its page was reloaded and its websocket reached the new server's viser.
    assert "reload=" in page.locator("#scene").get_attribute("src")
    page.frame_locator("#scene").locator("canvas").first.wait_for(timeout=60_000)
    page.click("#step")
    wait_for(
        lambda: any(t > started for t in frames), timeout=60, what="scene frames from the restarted server", page=page
    )
    assert page_errors(page) == []  # no uncaught "Failed to fetch" while the server was gone
