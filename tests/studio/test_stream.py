"""`GET /api/stream` against a real server (a subprocess), read as a browser's EventSource reads it:
httpx streaming the Server-Sent Events. Scene events after scene commands and none while nothing
changes; a runs event after a run is launched, and its status to the end; a run's metrics rows and log
lines; a rollout's history rows."""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator

import pytest

from tests.studio.conftest import StudioProcess, write_arg_file, write_checkpoint_dir

pytestmark = pytest.mark.integration


class EventReader:
    """Events of one open stream, parsed from the wire: (event name, JSON data)."""

    def __init__(self, server: StudioProcess, query: str = "") -> None:
        self._cm = server.client.stream("GET", f"/api/stream{query}", timeout=20)
        self.response = self._cm.__enter__()
        self._lines = self.response.iter_lines()
        self.seen: list[tuple[str, object]] = []

    def next(self) -> tuple[str, object]:
        name, data = "message", []
        for line in self._lines:
            if line == "":
                if data:
                    event = (name, json.loads("\n".join(data)))
                    self.seen.append(event)
                    return event
                name, data = "message", []  # a comment-only block (keep-alive)
            elif line.startswith("event: "):
                name = line[7:]
            elif line.startswith("data: "):
                data.append(line[6:])
        raise AssertionError("the stream ended")

    def until(self, pred: Callable[[str, object], bool], timeout: float = 15.0, what: str = "an event") -> object:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:  # heartbeats every 5 s keep this loop turning
            name, data = self.next()
            if pred(name, data):
                return data
        raise AssertionError(f"no {what} within {timeout} s; saw {[n for n, _ in self.seen[-20:]]}")

    def during(self, seconds: float) -> list[tuple[str, object]]:
        """Every event in the next `seconds` (ends at the first event after that)."""
        deadline = time.monotonic() + seconds
        out = []
        while time.monotonic() < deadline:
            out.append(self.next())
        return out

    def close(self) -> None:
        self._cm.__exit__(None, None, None)


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[StudioProcess]:
    runs_dir = tmp_path_factory.mktemp("stream_runs")
    write_arg_file(runs_dir, "short", rows=8, period=0.1)
    s = StudioProcess(runs_dir)  # the demo squat plays at start
    yield s
    s.stop()


@pytest.fixture
def events(server: StudioProcess) -> Iterator[Callable[[str], EventReader]]:
    opened: list[EventReader] = []

    def open_stream(query: str = "") -> EventReader:
        opened.append(EventReader(server, query))
        return opened[-1]

    yield open_stream
    for r in opened:
        r.close()


def test_scene_events_follow_scene_commands(server: StudioProcess, events) -> None:
    stream = events()
    assert stream.response.headers["content-type"].startswith("text/event-stream")
    name, hello = stream.next()
    assert name == "hello" and len(hello["server"]) == 32
    assert hello["topics"] == ["evals", "rollout", "runs", "scene", "videos"]
    first = stream.until(lambda n, d: n == "scene", what="the scene at connect")
    assert first["mode"] == "clip" and first["clip"].endswith("humanoid_demo_squat.pkl")

    assert server.post("/api/scene/pause").status_code == 200
    stream.until(lambda n, d: n == "scene" and d["playing"] is False, what="a scene event after pause")
    assert server.post("/api/scene/seek", {"frame": 7}).status_code == 200
    shown = stream.until(lambda n, d: n == "scene" and d["frame"] == 7, what="a scene event after seek")
    assert shown["playing"] is False
    # Paused, nothing changes: no scene events, only the heartbeat (every 5 s).
    quiet = stream.during(6.0)
    assert [n for n, _ in quiet if n == "scene"] == []
    assert "heartbeat" in [n for n, _ in quiet]
    server.post("/api/scene/play")
    stream.until(lambda n, d: n == "scene" and d["playing"] and d["frame"] != 7, what="frames while playing")


def test_runs_event_after_a_launch_and_on_each_change(server: StudioProcess, events) -> None:
    stream = events("?topics=runs")
    assert stream.next()[0] == "hello"
    before = stream.until(lambda n, d: n == "runs", what="the run list at connect")
    run = server.post("/api/runs", {"arg_file": "args/short.txt", "name": "pushed"}).json()
    assert run["id"] not in [r["id"] for r in before]
    listed = stream.until(lambda n, d: n == "runs" and any(r["id"] == run["id"] for r in d), what="the new run")
    row = next(r for r in listed if r["id"] == run["id"])
    assert row["name"] == "pushed" and "duration_s" not in row
    done = stream.until(
        lambda n, d: n == "runs" and any(r["id"] == run["id"] and r["status"] == "finished" for r in d),
        timeout=30,
        what="the run finished",
    )
    assert next(r for r in done if r["id"] == run["id"])["summary"]["samples"] > 0
    # An ended run does not change: no runs event re-sent with the same content.
    assert [n for n, _ in stream.during(3.0) if n == "runs"] == []


def test_a_runs_metrics_rows_and_log_lines(server: StudioProcess, events) -> None:
    run = server.post("/api/runs", {"arg_file": "args/short.txt", "name": "followed"}).json()
    live = events(f"?run={run['id']}")
    assert live.next()[1]["topics"] == ["evals", "log", "metrics", "rollout", "runs", "scene", "videos"]
    rows: list[dict] = []
    batches = 0
    while len(rows) < 8:
        m = live.until(lambda n, d: n == "metrics", timeout=30, what="metrics rows")
        assert m["run"] == run["id"] and m["start"] == len(rows) and m["reset"] == (batches == 0)
        rows += m["rows"]
        batches += 1
    stream_lines = [line for n, d in live.seen if n == "log" for line in d["lines"]]
    server_rows = server.get(f"/api/runs/{run['id']}/metrics", params={"follow": "false"}).json()
    assert rows == server_rows[: len(rows)] and len(rows) == 8
    assert [r["iteration"] for r in rows] == list(range(rows[0]["iteration"], rows[0]["iteration"] + 8))
    while not stream_lines:
        stream_lines += live.until(lambda n, d: n == "log", what="log lines")["lines"]
    assert stream_lines[0].startswith("$ ")  # each start of the trainer begins with its command line

    # Connecting after the end: the whole file at once, marked reset (the page starts its curves again).
    late = events(f"?run={run['id']}&topics=metrics")
    late.next()
    batch = late.until(lambda n, d: n == "metrics", what="the backlog")
    assert batch["reset"] is True and batch["start"] == 0 and batch["rows"] == server_rows


def test_rollout_history_rows(server: StudioProcess, events) -> None:
    checkpoint = write_checkpoint_dir(server.runs_dir / "ckpt-stream")
    stream = events("?topics=rollout")
    stream.next()
    assert server.post("/api/scene/load_rollout", {"checkpoint": str(checkpoint)}).status_code == 200
    try:
        # The new rollout's first event starts the page's plot again; it may come before any step has
        # terms (rows [], when the stream reads the rollout right after its load).
        first = stream.until(lambda n, d: n == "rollout", timeout=30, what="the new rollout's first event")
        assert first["reset"] is True
        if not first["rows"]:
            first = stream.until(lambda n, d: n == "rollout" and d["rows"], timeout=30, what="rollout rows")
        assert set(first["reward_weights"]) <= set(first["rows"][0]["terms"])
        later = stream.until(lambda n, d: n == "rollout" and not d["reset"] and d["rows"], what="more rollout rows")
        assert later["rows"][0]["step"] > first["rows"][-1]["step"]
    finally:
        server.post("/api/scene/rollout/close")


def test_refusals_are_one_line(server: StudioProcess) -> None:
    for query, status, words in (
        ("?topic=scene", 400, "did you mean 'topics'"),
        ("?topics=scene,runz", 400, "did you mean 'runs'"),
        ("?topics=metrics", 400, "need a run"),
        ("?run=9999", 404, "9999"),
    ):
        r = server.get(f"/api/stream{query}")
        assert r.status_code == status, query
        assert words in r.json()["detail"], r.json()
