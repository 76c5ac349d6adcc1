"""Run endpoints: launch, list, inspect, stop, resume, delete, and the live metrics stream."""

from __future__ import annotations

import json
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

from fastapi import APIRouter, Header, Query, Request, Response
from fastapi.responses import StreamingResponse
from pydantic import BaseModel, Field

from studio.api import studio_of
from studio.metrics import METRICS_FILE, follow_rows, read_rows
from studio.registry import Run
from studio.runs import CHECKPOINT
from studio.security import confine

router = APIRouter(prefix="/runs", tags=["runs"])


class LaunchRun(BaseModel):
    arg_file: str = Field(description="a MimicKit arg file (`args/*.txt` of the project or a data folder)")
    name: str | None = None
    num_envs: int | None = Field(None, gt=0)
    max_samples: int | None = Field(None, gt=0)
    motion_file: str | None = Field(None, description="a clip or dataset yaml that overrides the arg file's")


def _run_json(run: Run) -> dict[str, Any]:
    d = run.to_json()
    out = Path(run.out_dir) if run.out_dir else None
    d["checkpoint"] = str(out / CHECKPOINT) if out and (out / CHECKPOINT).is_file() else None
    d["duration_s"] = ((run.ended_at or time.time()) - run.started_at) if run.started_at else None
    return d


@router.get("")
def list_runs(request: Request) -> list[dict[str, Any]]:
    return [_run_json(r) for r in studio_of(request).registry.list()]


@router.post("", status_code=201)
def launch(body: LaunchRun, request: Request) -> dict[str, Any]:
    """Queue a training run (`mimickit train --arg_file ... --out_dir <runs-dir>/<id>-<name>`); it
    starts when fewer than `--max-concurrent-runs` runs are going."""
    studio = studio_of(request)
    roots = [*studio.settings.arg_dirs, *studio.settings.readable_roots]
    arg_file = confine(body.arg_file, roots)
    config: dict[str, Any] = {"arg_file": str(arg_file)}
    if body.motion_file:
        config["motion_file"] = str(confine(body.motion_file, studio.settings.readable_roots))
    for key in ("num_envs", "max_samples"):
        if getattr(body, key) is not None:
            config[key] = getattr(body, key)
    name = body.name or f"{arg_file.stem}-{time.strftime('%Y%m%d-%H%M%S')}"
    return _run_json(studio.runs.submit(name, config))


@router.get("/{run_id}")
def get_run(run_id: int, request: Request) -> dict[str, Any]:
    return _run_json(studio_of(request).runs.get(run_id))


@router.post("/{run_id}/stop")
def stop(run_id: int, request: Request) -> dict[str, Any]:
    """SIGTERM: the trainer writes its checkpoint and exits; the run becomes `stopped`."""
    return _run_json(studio_of(request).runs.stop(run_id))


@router.post("/{run_id}/resume")
def resume(run_id: int, request: Request) -> dict[str, Any]:
    """A new process in the same out_dir with `--model_file <out_dir>/model.pt`."""
    return _run_json(studio_of(request).runs.resume(run_id))


@router.delete("/{run_id}", status_code=204)
def delete(run_id: int, request: Request) -> Response:
    """Remove the run and its folder (a running run must be stopped first)."""
    studio_of(request).runs.delete(run_id)
    return Response(status_code=204)


@router.get("/{run_id}/log")
def log_tail(run_id: int, request: Request, lines: int = Query(200, gt=0, le=5000)) -> dict[str, Any]:
    """The last lines of the run's console output."""
    run = studio_of(request).runs.get(run_id)
    path = Path(run.out_dir) / "console.log"
    text = path.read_text(errors="replace") if path.is_file() else ""
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
    path = Path(run.out_dir) / METRICS_FILE
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
