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
  (read when its queue says a job changed);
- `videos`: the MP4 export jobs (`GET /api/videos`), sent at connect and when a job's status changed
  (read when its queue says a job changed);
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

import functools
import time
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Annotated, Any

import anyio.to_thread
from fastapi import APIRouter, Depends, HTTPException, Query, Request
from fastapi.sse import EventSourceResponse, ServerSentEvent

from mimickit.learning.run_folder import RunFolder
from mimickit.util.config import nearest_name
from studio.api import StudioDep, need, studio_of
from studio.api.bodies import OneLineErrors
from studio.jobs.kinds import JOB_KINDS
from studio.jobs.queue import JobQueue
from studio.live_state import (
    ONCE_A_SECOND,
    RUN_VOLATILE_KEYS,
    LiveState,
    LogFollower,
    MetricsFollower,
    RolloutFollower,
    Sampled,
)
from studio.services import Studio

router = APIRouter(tags=["stream"], route_class=OneLineErrors)
TOPICS = ("scene", "rollout", "runs", *(kind.folder_name for kind in JOB_KINDS), "metrics", "log")
RUN_TOPICS = ("metrics", "log")
QUERY_KEYS = ("topics", "run", "token")
HEARTBEAT_S = 5.0
FOLLOW_PERIOD_S = 0.5  # how often a subscribed run's files are checked for new rows and lines
RETRY_MS = 1000


def live_state(studio: Studio) -> LiveState:
    """The studio's topics every stream shares: each one's name (its event) and how it is read. The run
    list is read when the registry is written and compared once a second besides (a checkpoint's mtime
    changes without a registry write); a job list is read when its queue says a job changed."""
    topics = {
        "scene": Sampled(lambda: _scene_state(studio)),
        "runs": Sampled(lambda: _run_list(studio), every=ONCE_A_SECOND),
    }
    topics |= {name: Sampled(functools.partial(_job_list, jobs), every=None) for name, jobs in studio.jobs.items()}
    live = LiveState(topics)
    for name, jobs in studio.jobs.items():
        jobs.on_change = functools.partial(live.wake, name)
    studio.registry.on_write = functools.partial(live.wake, "runs")  # at once; checkpoints: the 1 s check
    return live


def _scene_state(studio: Studio) -> dict[str, Any] | None:
    target = studio.active()
    return target.snapshot() if target is not None else None


def _run_list(studio: Studio) -> list[dict[str, Any]]:
    rows = []
    for run in studio.registry.list():
        row = {k: v for k, v in studio.run_list.row(run).items() if k not in RUN_VOLATILE_KEYS}
        row["checkpoint_mtime"] = _mtime(row.get("checkpoint"))
        rows.append(row)
    return rows


def _job_list(jobs: JobQueue) -> list[dict[str, Any]]:
    return [j.to_json() for j in jobs.list()]


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


class Followers:
    """One stream's own parts: the rollout's new history rows (read when the scene changed) and one run's
    new metrics rows and log lines, read in a worker thread."""

    def __init__(self, sub: Subscription, studio: Studio) -> None:
        folder = RunFolder(sub.run_dir) if sub.run_dir is not None else None
        self.scene, self.run = studio.scene, sub.run
        self.rollout = RolloutFollower() if "rollout" in sub.topics else None
        self.metrics = MetricsFollower(folder.metrics_file) if folder and "metrics" in sub.topics else None
        self.log = LogFollower(folder.console_file) if folder and "log" in sub.topics else None

    @property
    def follow_run(self) -> bool:
        return self.metrics is not None or self.log is not None

    async def events(self, scene_changed: bool) -> list[ServerSentEvent]:
        events = []
        if self.rollout is not None and scene_changed:
            rows = self.rollout.read(self.scene.rollout)  # what the scene thread published: no wait
            events += [ServerSentEvent(event="rollout", data=rows)] if rows is not None else []
        if self.metrics is not None:
            batches = await _in_thread(self.metrics.read)
            events += [ServerSentEvent(event="metrics", data={"run": self.run, **b}) for b in batches]
        if self.log is not None:
            lines = await _in_thread(self.log.read)
            events += [ServerSentEvent(event="log", data={"run": self.run, **lines})] if lines is not None else []
        return events


async def _in_thread(fn: Callable[..., Any], *args: Any) -> Any:
    return await anyio.to_thread.run_sync(fn, *args)


def _news(live: LiveState, seen: dict[str, int], wanted: frozenset[str]) -> tuple[list[ServerSentEvent], bool]:
    """An event of each wanted topic newer than `seen` (now updated), and whether the scene changed."""
    events, scene_changed = [], False
    for name, topic in live.topics.items():
        if topic.version == seen[name]:
            continue
        seen[name] = topic.version
        scene_changed |= name == "scene"
        if name in wanted and topic.value is not None:
            events.append(ServerSentEvent(event=name, data=topic.value))
    return events, scene_changed


@router.get("/stream", response_class=EventSourceResponse)
async def stream(sub: Annotated[Subscription, Depends()], studio: StudioDep) -> AsyncIterator[ServerSentEvent]:
    """Scene state, rollout history, run list, eval and video jobs, and one run's metrics rows and log lines,
    pushed when they change (see the module's text for the events)."""
    live = studio.live
    need(live, "the stream")
    hello = {"server": live.server_id, "topics": sorted(sub.topics), "run": sub.run, "heartbeat_s": HEARTBEAT_S}
    yield ServerSentEvent(event="hello", data=hello, retry=RETRY_MS)
    followers = Followers(sub, studio)
    seen = dict.fromkeys(live.topics, -1)
    last_sent = time.monotonic()
    async with live.subscribe():
        while True:
            events, scene_changed = _news(live, seen, sub.topics)
            events += await followers.events(scene_changed)
            for event in events:
                yield event
            now = time.monotonic()
            if events:
                last_sent = now
            elif now - last_sent >= HEARTBEAT_S:
                yield ServerSentEvent(event="heartbeat", data={"time": time.time()})
                last_sent = now
            timeout = HEARTBEAT_S - (time.monotonic() - last_sent)
            if followers.follow_run:
                timeout = min(timeout, FOLLOW_PERIOD_S)
            await live.wait(tuple(seen.values()), max(0.01, timeout))
