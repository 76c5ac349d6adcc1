"""`GET /api/stream`: one Server-Sent Events stream of what the page shows, pushed when it changes.

Events (each `data:` is JSON):

- `hello` first: `server` (a new id per server start: the page reloads the 3D scene when it changes),
  `topics`, `run`, `heartbeat_s`;
- `scene`: the scene state (`GET /api/scene/state`), sent at connect and whenever it changed (at most
  10 a second; nothing while paused);
- `rollout`: the loaded rollout's new history rows `{reset, step, reward_weights, rows}` (`reset`: a
  new rollout, checkpoint or step numbering: start the plot again);
- `runs`: the run list (`GET /api/runs` rows without the clock-driven `duration_s`, plus
  `checkpoint_mtime`), sent at connect and when a run's content changed (checked once a second);
- `evals`: the eval jobs (`GET /api/evals`), sent at connect and when a job's status or rows changed
  (checked once a second);
- `videos`: the MP4 export jobs (`GET /api/videos`), sent at connect and when a job's status changed
  (checked once a second);
- `metrics` (with `?run=ID`): that run's new `metrics.jsonl` rows `{run, reset, start, rows}`
  (`start` = the first row's index; the first batch has `reset`);
- `log` (with `?run=ID`): that run's new `console.log` lines `{run, reset, lines}`;
- `heartbeat` every few seconds `{time}`: a page that hears nothing for three of them treats the server
  as gone (and proxies see traffic).

Files, SQLite and the eval jobs are read in worker threads (`studio.live_state`), never on the event loop. The
route sits under `/api`, so the Host, Origin and token checks of `RequestGuard` apply (an
EventSource cannot send headers: `?token=`).
"""

from __future__ import annotations

import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Annotated, Any

import anyio.to_thread
from fastapi import APIRouter, Depends, HTTPException, Query, Request
from fastapi.sse import EventSourceResponse, ServerSentEvent

from mimickit.run_folder import RunFolder
from mimickit.util.config import nearest_name
from studio.api import studio_of
from studio.api.bodies import OneLineErrors
from studio.api.runs import run_json
from studio.live_state import RUN_VOLATILE_KEYS, LiveState, LogFollower, MetricsFollower, RolloutFollower

router = APIRouter(tags=["stream"], route_class=OneLineErrors)
TOPICS = ("scene", "rollout", "runs", "evals", "videos", "metrics", "log")
RUN_TOPICS = ("metrics", "log")
QUERY_KEYS = ("topics", "run", "token")
HEARTBEAT_S = 5.0
FOLLOW_PERIOD_S = 0.5  # how often a subscribed run's files are checked for new rows and lines
RETRY_MS = 1000


def live_of(request: Request) -> LiveState:
    """The app's one `LiveState`, made on first use (on the event loop, so no race)."""
    state = request.app.state
    if getattr(state, "live", None) is None:
        studio = studio_of(request)
        state.live = LiveState(
            lambda: _scene_state(studio),
            lambda: _run_list(studio),
            lambda: _eval_list(state),
            lambda: _video_list(state),
        )
    return state.live


def _scene_state(studio: Any) -> dict[str, Any] | None:
    target = studio.active()
    return target.snapshot() if target is not None else None


def _run_list(studio: Any) -> list[dict[str, Any]]:
    rows = []
    for run in studio.registry.list():
        row = {k: v for k, v in run_json(run).items() if k not in RUN_VOLATILE_KEYS}
        row["checkpoint_mtime"] = _mtime(row.get("checkpoint"))
        rows.append(row)
    return rows


def _eval_list(state: Any) -> list[dict[str, Any]]:
    jobs = getattr(state, "evals", None)  # made at start-up (or by the first `/api/evals` request)
    return [j.to_json() for j in jobs.list()] if jobs is not None else []


def _video_list(state: Any) -> list[dict[str, Any]]:
    jobs = getattr(state, "videos", None)  # made at start-up (or by the first `/api/videos` request)
    return [j.to_json() for j in jobs.list()] if jobs is not None else []


def _mtime(path: str | None) -> float | None:
    try:
        return Path(path).stat().st_mtime if path else None
    except OSError:
        return None


class Subscription:
    """What one stream asked for: `topics` (comma-separated) and `run`."""

    def __init__(
        self,
        request: Request,
        topics: str | None = Query(None, description=f"comma-separated, of {', '.join(TOPICS)} (default: all)"),
        run: int | None = Query(None, description="a run whose metrics rows and log lines to stream"),
    ) -> None:
        for key in request.query_params:
            if key not in QUERY_KEYS:
                near = nearest_name(key, list(QUERY_KEYS))
                hint = f"; did you mean {near!r}?" if near else f"; known: {', '.join(QUERY_KEYS)}"
                raise HTTPException(400, f"unknown query parameter {key!r}{hint}")
        wanted = [t.strip() for t in topics.split(",") if t.strip()] if topics is not None else None
        for t in wanted or ():
            if t not in TOPICS:
                near = nearest_name(t, list(TOPICS))
                hint = f"; did you mean {near!r}?" if near else f"; known topics: {', '.join(TOPICS)}"
                raise HTTPException(400, f"unknown topic {t!r}{hint}")
        if wanted is None:
            wanted = [t for t in TOPICS if run is not None or t not in RUN_TOPICS]
        if run is None and any(t in RUN_TOPICS for t in wanted):
            raise HTTPException(400, "topics metrics and log need a run: add ?run=ID")
        self.topics = frozenset(wanted)
        self.run_dir = Path(studio_of(request).runs.get(run).out_dir) if run is not None else None  # 404: no run
        self.run = run


@router.get("/stream", response_class=EventSourceResponse)
async def stream(request: Request, sub: Annotated[Subscription, Depends()]) -> AsyncIterator[ServerSentEvent]:
    """Scene state, rollout history, run list, eval and video jobs, and one run's metrics rows and log lines,
    pushed when they change (see the module's text for the events)."""
    studio = studio_of(request)
    live = live_of(request)
    hello = {"server": live.server_id, "topics": sorted(sub.topics), "run": sub.run, "heartbeat_s": HEARTBEAT_S}
    yield ServerSentEvent(event="hello", data=hello, retry=RETRY_MS)
    folder = RunFolder(sub.run_dir) if sub.run_dir is not None else None
    metrics = MetricsFollower(folder.metrics_file) if folder and "metrics" in sub.topics else None
    log = LogFollower(folder.console_file) if folder and "log" in sub.topics else None
    rollout = RolloutFollower() if "rollout" in sub.topics else None
    seen_scene = seen_runs = seen_evals = seen_videos = -1
    last_sent = time.monotonic()
    async with live.subscribe():
        while True:
            sent = False
            if live.scene.version != seen_scene:
                seen_scene = live.scene.version
                scene = live.scene.value
                if "scene" in sub.topics and scene is not None:
                    yield ServerSentEvent(event="scene", data=scene)
                    sent = True
                if rollout is not None:
                    rp = studio.rollout  # no rollout loaded: nothing to read, no worker thread (10 a second)
                    rows = rollout.read(None) if rp is None else await anyio.to_thread.run_sync(rollout.read, rp)
                    if rows is not None:
                        yield ServerSentEvent(event="rollout", data=rows)
                        sent = True
            if live.runs.version != seen_runs:
                seen_runs = live.runs.version
                if "runs" in sub.topics:
                    yield ServerSentEvent(event="runs", data=live.runs.value)
                    sent = True
            if live.evals.version != seen_evals:
                seen_evals = live.evals.version
                if "evals" in sub.topics:
                    yield ServerSentEvent(event="evals", data=live.evals.value)
                    sent = True
            if live.videos.version != seen_videos:
                seen_videos = live.videos.version
                if "videos" in sub.topics:
                    yield ServerSentEvent(event="videos", data=live.videos.value)
                    sent = True
            if metrics is not None:
                for batch in await anyio.to_thread.run_sync(metrics.read):
                    yield ServerSentEvent(event="metrics", data={"run": sub.run, **batch})
                    sent = True
            if log is not None:
                lines = await anyio.to_thread.run_sync(log.read)
                if lines is not None:
                    yield ServerSentEvent(event="log", data={"run": sub.run, **lines})
                    sent = True
            now = time.monotonic()
            if sent:
                last_sent = now
            elif now - last_sent >= HEARTBEAT_S:
                yield ServerSentEvent(event="heartbeat", data={"time": time.time()})
                last_sent = now
            timeout = HEARTBEAT_S - (time.monotonic() - last_sent)
            if metrics is not None or log is not None:
                timeout = min(timeout, FOLLOW_PERIOD_S)
            await live.wait((seen_scene, seen_runs, seen_evals, seen_videos), max(0.01, timeout))
