"""The run list as the API and the stream give it: each run's registry row with what its folder says
(`checkpoint`, `summary`) and its duration. One `RunList` per studio (`Studio.run_list`): it reads the
list in a worker thread and serves it again while the registry has not changed, and it reads an ended
run's folder once."""

from __future__ import annotations

import threading
import time
from typing import Any

from mimickit.learning.run_folder import RunFolder
from studio.runs.registry import Registry, Run, RunStatus
from studio.runs.summary import empty_summary, run_summary

RUN_LIST_TTL_S = 0.5  # how long a run list is served again while the registry has not changed
ENDED_MAX = 100_000  # ended runs whose folder fields are kept (a registry of more is read again, never wrong)


class RunList:
    """The run list, read (SQLite, each run folder's files) in a worker thread and served again from
    the event loop while no registry write happened and it is under `RUN_LIST_TTL_S` old: 40 clients
    asking several times a second cost one read, not one worker thread each (whose hand-offs, GIL
    contention mostly, were most of the API's p99 under load). A run's own files (new metrics rows, a
    checkpoint) show at most that late; a launch, stop or delete at once. `duration_s` is recomputed
    on every answer."""

    def __init__(self, registry: Registry) -> None:
        self.registry = registry
        self._cached: tuple[int, float, list[tuple[Run, dict[str, Any]]]] | None = None
        self._lock = threading.Lock()
        self._ended: dict[int, tuple[tuple[Any, ...], dict[str, Any]]] = {}

    def row(self, run: Run) -> dict[str, Any]:
        """`run` as `GET /api/runs/{id}` gives it."""
        return {**run.to_json(), **self._folder_fields(run), "duration_s": _duration(run, time.time())}

    def fresh(self) -> list[dict[str, Any]] | None:
        """The cached list when it is still current (cheap: for the event loop), else None."""
        cached = self._cached
        if cached is None or cached[0] != self.registry.writes or time.monotonic() - cached[1] > RUN_LIST_TTL_S:
            return None
        now = time.time()
        return [{**d, "duration_s": _duration(run, now)} for run, d in cached[2]]

    def read(self) -> list[dict[str, Any]]:
        """Read the list again (blocking: a worker thread's job) and cache it."""
        with self._lock:  # concurrent misses read once: the later ones find the fresh list
            hit = self.fresh()
            if hit is not None:
                return hit
            writes, at = self.registry.writes, time.monotonic()  # before the read: a write during it is seen
            rows = [(run, self.row(run)) for run in self.registry.list()]
            self._cached = (writes, at, rows)
            return [d for _, d in rows]

    def _folder_fields(self, run: Run) -> dict[str, Any]:
        """What the run's folder says (`checkpoint`, `summary`). An ended run's folder no longer changes
        (a resume queues it again first), so it is read once, not on every list: with thousands of runs
        the list would otherwise stat and parse every folder each time. A run no process has started has
        none."""
        key = (run.out_dir, run.status, run.ended_at, run.attempts)
        hit = self._ended.get(run.id) if run.status.finished else None
        if hit is not None and hit[0] == key:
            return hit[1]
        if not run.out_dir:
            return {"checkpoint": None, "summary": None}
        if run.attempts == 0 and run.status in (RunStatus.QUEUED, RunStatus.STOPPED):  # never started: no files
            return {"checkpoint": None, "summary": empty_summary(run.out_dir)}
        folder = RunFolder(run.out_dir)
        fields = {
            "checkpoint": str(folder.model_file) if folder.model_file.is_file() else None,
            "summary": run_summary(run.out_dir),
        }
        if run.status.finished:
            if len(self._ended) >= ENDED_MAX:
                self._ended.clear()
            self._ended[run.id] = (key, fields)
        return fields


def _duration(run: Run, now: float) -> float | None:
    return ((run.ended_at or now) - run.started_at) if run.started_at else None
