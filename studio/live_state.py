"""What `GET /api/stream` pushes, read off the event loop: one watcher per server samples a table of
topics (the stream's: the scene 10 times a second, the run list once a second, the eval and video jobs
when their queue says one changed: `wake`) in a worker thread while at least one stream is open, and
wakes the streams when one changed, compared by content. Nothing is sampled while no stream is open.
Each stream's own part (a rollout's new history rows, one run's new metrics rows and log lines) is read
by the followers below, also in a worker thread.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import threading
import uuid
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import anyio.to_thread

from studio.runs.metrics import RowReader

LOG = logging.getLogger("studio")
PERIOD_S = 0.1  # the watcher's tick: a topic is sampled every `Sampled.every` ticks
ONCE_A_SECOND = 10
ROLLOUT_BACKLOG_ROWS = 600  # 20 s at 30 Hz: what a new stream gets of the rollout's history (the plot shows 10 s)
LOG_BACKLOG_LINES = 200
LOG_TAIL_BYTES = 64 * 1024
METRICS_BATCH_ROWS = 500  # one event carries at most this many rows (a long run's backlog is several events)
RUN_VOLATILE_KEYS = ("duration_s",)  # grows with the clock, not a change of the run: left out of the stream


@dataclass
class Versioned:
    """A value and a counter that grows each time the value's content changes."""

    value: Any = None
    version: int = 0
    _key: str | None = None

    def update(self, value: Any) -> bool:
        key = json.dumps(value, sort_keys=True, default=str)
        if key == self._key:
            return False
        self.value, self._key, self.version = value, key, self.version + 1
        return True


@dataclass(frozen=True)
class Sampled:
    """How the watcher reads a topic's value: `read()` in a worker thread, every `every` ticks (None:
    only when a stream starts the watcher and at the tick after each `LiveState.wake(topic)`)."""

    read: Callable[[], Any]
    every: int | None = 1


class LiveState:
    """The values of `sampled` (topic name: how to read it), sampled while someone listens (`subscribe`);
    `topics[name]` is a topic's value and version."""

    def __init__(self, sampled: dict[str, Sampled]) -> None:
        self.server_id = uuid.uuid4().hex  # a new one per server start: the page sees a restart
        self.topics = {name: Versioned() for name in sampled}
        self._sampled = dict(sampled)
        self._woken: set[str] = set()  # topics to read at the next tick, whatever their period
        self._woken_lock = threading.Lock()  # `wake` comes from any thread
        self._listeners = 0
        self._task: asyncio.Task | None = None
        self._ready = asyncio.Event()
        self._changed = asyncio.Event()

    @property
    def watching(self) -> bool:
        return self._task is not None and not self._task.done()

    @contextlib.asynccontextmanager
    async def subscribe(self) -> AsyncIterator[None]:
        """While inside, the watcher runs (one for all listeners); a listener starts once the watcher
        has taken a fresh sample, so what it sends first is the state now, not when the last page left."""
        self._listeners += 1
        try:
            if not self.watching:
                self._ready = asyncio.Event()
                self._task = asyncio.get_running_loop().create_task(self._watch(self._ready))
            await self._ready.wait()
            yield
        finally:
            self._listeners -= 1
            if self._listeners == 0 and self._task is not None:
                self._task.cancel()
                self._task = None

    @property
    def versions(self) -> tuple[int, ...]:
        """The topics' versions, in the order of `topics`."""
        return tuple(v.version for v in self.topics.values())

    async def wait(self, seen: tuple[int, ...], timeout: float) -> None:
        """Until a topic is newer than `seen` (`versions`), or `timeout` seconds."""
        if self.versions != seen:
            return
        event = self._changed
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(event.wait(), timeout)

    def wake(self, topic: str) -> None:
        """Read `topic` at the next tick (within `PERIOD_S`): its source says it changed. Any thread."""
        if topic not in self._sampled:
            raise KeyError(f"no topic {topic!r}; known: {', '.join(self._sampled)}")
        with self._woken_lock:
            self._woken.add(topic)

    async def _watch(self, ready: asyncio.Event) -> None:
        await self._sample(0)  # every topic
        ready.set()
        tick = 0
        while True:
            await asyncio.sleep(PERIOD_S)
            tick += 1
            await self._sample(tick)

    async def _sample(self, tick: int) -> None:
        with self._woken_lock:
            woken, self._woken = self._woken, set()
        due = [n for n, s in self._sampled.items() if tick == 0 or n in woken or (s.every and tick % s.every == 0)]

        def read() -> list[bool]:
            return [self.topics[n].update(_guarded(self._sampled[n].read, n, self.topics[n].value)) for n in due]

        if any(await anyio.to_thread.run_sync(read)):
            # Wake every waiting stream at once; later waiters get a fresh event.
            self._changed.set()
            self._changed = asyncio.Event()


def _guarded(read: Callable[[], Any], topic: str, last: Any) -> Any:
    """A failing read keeps the last value (and says so in the log): one bad sample must not end the
    watcher, which every open page depends on."""
    try:
        return read()
    except Exception as e:  # noqa: BLE001 - logged with its traceback; the stream goes on
        LOG.warning("live state: reading %s failed", topic, exc_info=e)
        return last


class RolloutFollower:
    """A rollout's history rows not sent yet, read from what the scene thread published (`Playable.feed`:
    no command to the scene thread); starts again (`reset`) when another rollout, a reloaded checkpoint or
    a new episode numbering (step going back) appears."""

    def __init__(self) -> None:
        self._shown: tuple[int, Any, Any] | None = None
        self._seen: int | None = None  # the version of the feed read last
        self._last_step = -1

    def read(self, rollout_player: Any) -> dict[str, Any] | None:
        if rollout_player is None:
            self._shown = self._seen = None
            return None
        feed = rollout_player.feed()
        if feed is None or feed.version == self._seen:
            return None
        self._seen = feed.version
        snap = feed.state["rollout"]
        key = (id(rollout_player), snap.get("checkpoint"), snap.get("reloads"))
        reset = key != self._shown or snap["step"] < self._last_step
        if reset:
            self._shown, self._last_step = key, -1
        rows = [r for r in feed.rows if r["step"] > self._last_step][-ROLLOUT_BACKLOG_ROWS:]
        if not rows and not reset:
            return None
        if rows:
            self._last_step = rows[-1]["step"]
        return {"reset": reset, "step": snap["step"], "reward_weights": snap.get("reward_weights"), "rows": rows}


class LogFollower:
    """New lines of a run's `console.log`: its last lines first, then what is appended; a file that
    shrank or vanished (a deleted run) starts again."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._pos: int | None = None
        self._pending = b""

    def read(self) -> dict[str, Any] | None:
        try:
            size = self.path.stat().st_size
        except OSError:
            size = 0
        reset = self._pos is None or size < self._pos
        if reset:
            start = max(0, size - LOG_TAIL_BYTES)
            self._pos, self._pending = start, b""
        elif size == self._pos:
            return None
        chunk = b""
        if size:
            with self.path.open("rb") as f:
                f.seek(self._pos)
                chunk = f.read(size - self._pos)
        self._pos += len(chunk)
        data = self._pending + chunk
        *lines, self._pending = data.split(b"\n")
        if reset and self._pos > len(chunk) and lines:
            lines = lines[1:]  # the tail may start mid-line
        text = [line.decode("utf-8", errors="replace").rstrip("\r") for line in lines]
        if not text and not reset:
            return None
        return {"reset": reset, "lines": text[-LOG_BACKLOG_LINES:]}


class MetricsFollower:
    """A run's metrics rows not sent yet, in batches of at most `METRICS_BATCH_ROWS`."""

    def __init__(self, path: Path) -> None:
        self._reader = RowReader(path)
        self._first = True

    def read(self) -> list[dict[str, Any]]:
        rows = self._reader.read()
        batches = []
        for i in range(0, len(rows), METRICS_BATCH_ROWS):
            part = rows[i : i + METRICS_BATCH_ROWS]
            batches.append({"reset": self._first and i == 0, "start": part[0][0], "rows": [r for _, r in part]})
        if self._first and not batches:
            batches.append({"reset": True, "start": 0, "rows": []})
        self._first = False
        return batches
