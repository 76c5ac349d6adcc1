"""Run endpoints: launch, list, inspect, stop, resume (with a new budget), again with a run's seed,
delete, and the live metrics stream.

Paths take the CLI's forms: `args/x.txt` (the project's args folder, then each data folder's and the
runs folder's), `data/...` (each data folder in turn), or absolute inside the allowed folders.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import AsyncIterator
from pathlib import Path, PurePosixPath
from typing import Any

import anyio.to_thread
from fastapi import APIRouter, Header, Query, Request, Response
from fastapi.responses import StreamingResponse
from pydantic import Field

from mimickit.run_args import MAX_NUM_ENVS, MAX_SEED
from mimickit.run_folder import RunFolder
from studio.api import studio_of
from studio.api.bodies import OneLineErrors, StrictBody
from studio.metrics import follow_rows, read_rows
from studio.registry import Registry, Run
from studio.run_summary import run_summary
from studio.security import PathError, confine
from studio.settings import Settings

router = APIRouter(prefix="/runs", tags=["runs"], route_class=OneLineErrors)
MOTION_SUFFIXES = (".pkl", ".yaml", ".yml")


class LaunchRun(StrictBody):
    arg_file: str = Field(description="a MimicKit arg file: `args/x.txt`, `data/args/x.txt` or an absolute path")
    name: str | None = Field(None, max_length=200)
    num_envs: int | None = Field(None, gt=0, le=MAX_NUM_ENVS)  # the trainer's bounds
    max_samples: int | None = Field(None, gt=0)
    max_hours: float | None = Field(None, gt=0, description="a wall-time budget: the trainer's --max_hours")
    motion_file: str | None = Field(None, description="a clip (.pkl) or dataset (.yaml) replacing the env config's")
    rand_seed: int | None = Field(None, ge=0, le=MAX_SEED, description="the seed (default: the trainer picks one)")
    num_cpus: float | None = Field(None, ge=0, le=1024, description="CPUs the run reserves (Ray executor; default 1)")
    num_gpus: float | None = Field(None, ge=0, le=64, description="GPUs the run reserves (Ray executor; default 0)")


class ResumeRun(StrictBody):
    max_samples: int | None = Field(None, gt=0, description="the new budget: total samples, more than trained")
    max_hours: float | None = Field(None, gt=0, description="the new wall-time budget: hours in all, more than trained")


def resolve_arg_file(path: str, settings: Settings) -> Path:
    """An arg file as the CLI names it: `args/x.txt` is looked up in each args folder (the project's
    first), anything else is a path of `confine` inside the arg and data folders."""
    parts = PurePosixPath(path.replace("\\", "/")).parts
    if len(parts) > 1 and parts[0] == "args":
        try:
            return confine(str(PurePosixPath(*parts[1:])), settings.arg_dirs)
        except PathError as e:
            if e.status != 404:
                raise
            raise PathError(f"arg file not found: {path}", 404) from None
    return confine(path, [*settings.arg_dirs, *settings.readable_roots])


def run_json(run: Run) -> dict[str, Any]:
    d = run.to_json()
    folder = RunFolder(run.out_dir) if run.out_dir else None
    d["checkpoint"] = str(folder.model_file) if folder and folder.model_file.is_file() else None
    d["duration_s"] = _duration(run, time.time())
    d["summary"] = run_summary(run.out_dir) if folder else None
    return d


RUN_LIST_TTL_S = 0.5  # how long a run list is served again while the registry has not changed


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
            rows = [(run, run_json(run)) for run in self.registry.list()]
            self._cached = (writes, at, rows)
            return [d for _, d in rows]


def run_list_of(request: Request) -> RunList:
    """The app's one `RunList`, made on first use (on the event loop, so no race)."""
    state = request.app.state
    if getattr(state, "run_list", None) is None:
        state.run_list = RunList(studio_of(request).registry)
    return state.run_list


def _duration(run: Run, now: float) -> float | None:
    return ((run.ended_at or now) - run.started_at) if run.started_at else None


@router.get("")
async def list_runs(request: Request) -> list[dict[str, Any]]:
    runs = run_list_of(request)
    rows = runs.fresh()
    return rows if rows is not None else await anyio.to_thread.run_sync(runs.read)


def resolve_motion_file(path: str, settings: Settings) -> Path:
    """A clip (.pkl) or dataset (.yaml) inside the readable folders, or PathError 400 naming it."""
    motion = confine(path, settings.readable_roots)
    if motion.suffix not in MOTION_SUFFIXES or not motion.is_file():
        raise PathError(f"motion_file must be a clip (.pkl) or a dataset (.yaml) file: {path}", 400)
    return motion


def run_config(body: LaunchRun, settings: Settings) -> dict[str, Any]:
    """What the registry keeps of a launch: the resolved arg file and clip, the overrides given, and
    the resources (1 CPU by default with Ray, so that Ray, not the studio, decides how many run at once)."""
    config: dict[str, Any] = {"arg_file": str(resolve_arg_file(body.arg_file, settings))}
    if body.motion_file:
        config["motion_file"] = str(resolve_motion_file(body.motion_file, settings))
    for key in ("num_envs", "max_samples", "max_hours", "rand_seed", "num_cpus", "num_gpus"):
        if getattr(body, key) is not None:
            config[key] = getattr(body, key)
    if settings.executor == "ray":
        config.setdefault("num_cpus", 1)
    return config


@router.post("", status_code=201)
def launch(body: LaunchRun, request: Request) -> dict[str, Any]:
    """Queue a training run (`mimickit train --arg_file ... --out_dir <runs-dir>/<id>-<name>`); it
    starts when fewer than `--max-concurrent-runs` runs are going (local executor) or when the Ray
    cluster has its `num_cpus`/`num_gpus` free (Ray executor)."""
    studio = studio_of(request)
    config = run_config(body, studio.settings)
    name = body.name or f"{Path(config['arg_file']).stem}-{time.strftime('%Y%m%d-%H%M%S')}"
    return run_json(studio.runs.submit(name, config))


@router.get("/{run_id}")
def get_run(run_id: int, request: Request) -> dict[str, Any]:
    return run_json(studio_of(request).runs.get(run_id))


@router.post("/{run_id}/stop")
def stop(run_id: int, request: Request) -> dict[str, Any]:
    """SIGTERM: the trainer writes its checkpoint and exits; the run becomes `stopped`."""
    return run_json(studio_of(request).runs.stop(run_id))


@router.post("/{run_id}/resume")
def resume(run_id: int, request: Request, body: ResumeRun | None = None) -> dict[str, Any]:
    """A new process in the same run folder with `--model_file <out_dir>/model.pt`; `max_samples` sets
    a new budget (needed to continue a run that reached its budget). The trainer marks the resume with a
    `{"event": "resume"}` row in metrics.jsonl."""
    budget = {"max_samples": body.max_samples, "max_hours": body.max_hours} if body else {}
    return run_json(studio_of(request).runs.resume(run_id, **budget))


@router.post("/{run_id}/again", status_code=201)
def again(run_id: int, request: Request) -> dict[str, Any]:
    """A new run with the same arg file and overrides, and the seed this run used (from its args.json)."""
    return run_json(studio_of(request).runs.again(run_id))


@router.delete("/{run_id}", status_code=204)
def delete(run_id: int, request: Request) -> Response:
    """Remove the run and its folder (a running run must be stopped first); a rollout of one of its
    checkpoints is stopped and cleared."""
    studio = studio_of(request)
    out_dir = studio.runs.get(run_id).out_dir
    studio.runs.delete(run_id)
    if out_dir and studio.rollout is not None and studio.rollout.plays_from(Path(out_dir)):
        studio.end_rollout()
    return Response(status_code=204)


@router.get("/{run_id}/log")
def log_tail(run_id: int, request: Request, lines: int = Query(200, gt=0, le=5000)) -> dict[str, Any]:
    """The last lines of the run's console output (a running Ray job's from Ray)."""
    text = studio_of(request).runs.logs(run_id)
    return {"lines": text.splitlines()[-lines:]}


@router.get("/{run_id}/metrics", response_model=None)
def metrics(
    run_id: int,
    request: Request,
    follow: bool = Query(True, description="stream rows as Server-Sent Events while the run goes"),
    start: int = Query(0, ge=0, description="first row index to send"),
    last_event_id: str | None = Header(None),
) -> StreamingResponse | list[dict[str, Any]]:
    """The run's `metrics.jsonl` rows. `follow=true` (default): an event stream, one `data:` event per
    row (its `id` is the row index, so a reconnecting EventSource resumes), ending with an `end` event
    once the run has finished; `follow=false`: the rows so far as one JSON list."""
    studio = studio_of(request)
    run = studio.runs.get(run_id)
    path = RunFolder(run.out_dir).metrics_file
    if not follow:
        return read_rows(path, start)
    if last_event_id and last_event_id.isdigit():
        start = max(start, int(last_event_id) + 1)

    def finished() -> bool:
        current = studio.registry.find(run_id)
        return current is None or current.status.finished

    async def events() -> AsyncIterator[str]:
        yield "retry: 2000\n\n"
        async for item in follow_rows(path, finished, start):
            if await request.is_disconnected():
                return
            if item is None:
                yield ": keep-alive\n\n"
            else:
                index, row = item
                yield f"id: {index}\ndata: {json.dumps(row)}\n\n"
        final = studio.registry.find(run_id)
        yield f"event: end\ndata: {json.dumps({'status': final.status.value if final else 'deleted'})}\n\n"

    headers = {"Cache-Control": "no-cache", "X-Accel-Buffering": "no"}
    return StreamingResponse(events(), media_type="text/event-stream", headers=headers)
