"""MP4 export endpoints: `mimickit video` of a clip or of a checkpoint's policy as a background job,
its status, stopping it, and the video. `GET /api/stream`'s `videos` event pushes the job list."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import FileResponse
from pydantic import Field, field_validator

from studio.api import studio_of
from studio.api.bodies import OneLineErrors, StrictBody
from studio.api.scene import _char_for
from studio.rollout import source_for_checkpoint
from studio.runs import CHECKPOINT
from studio.security import confine
from studio.settings import Settings
from studio.videos import VIDEO_FILE, VideoJob, VideoJobs

router = APIRouter(prefix="/videos", tags=["videos"], route_class=OneLineErrors)
MAX_SECONDS = 60.0
MAX_WIDTH, MAX_HEIGHT = 1920, 1080
CONFIG_KEYS = ("env_config", "agent_config", "engine_config")
_jobs_lock = threading.Lock()


class StartVideo(StrictBody):
    clip: str | None = Field(None, description="a clip (.pkl) to play kinematically")
    char: str | None = Field(None, description="the clip's MJCF character (default: guessed from its frame width)")
    run_id: int | None = Field(None, description="a run: its `model.pt` and the configs copied into its folder")
    checkpoint: str | None = Field(None, description="a checkpoint file inside the data or runs folders")
    env_config: str | None = Field(None, description="env yaml of the checkpoint (default: the one beside it)")
    agent_config: str | None = Field(None, description="agent yaml of the checkpoint (default: the one beside it)")
    engine_config: str | None = Field(None, description="engine yaml of the checkpoint (default: the one beside it)")
    seconds: float = Field(5.0, gt=0, le=MAX_SECONDS, description="length of the video")
    width: int = Field(640, ge=16, le=MAX_WIDTH, description="pixels, even")
    height: int = Field(480, ge=16, le=MAX_HEIGHT, description="pixels, even")

    @field_validator("width", "height")
    @classmethod
    def _even(cls, v: int) -> int:
        if v % 2:
            raise ValueError(f"must be even (H.264 halves it for colour), got {v}")
        return v


def jobs_in(state: Any, settings: Settings) -> VideoJobs:
    """The app's video jobs (`state.videos`), made on first use: the server makes them at start-up,
    listing the jobs recorded under `<runs-dir>/videos/` (their worker thread starts with them)."""
    with _jobs_lock:
        if getattr(state, "videos", None) is None:
            state.videos = VideoJobs(settings)
        return state.videos


def jobs_of(request: Request) -> VideoJobs:
    return jobs_in(request.app.state, studio_of(request).settings)


def _job(request: Request, job_id: int) -> VideoJob:
    job = jobs_of(request).get(job_id)
    if job is None:
        raise HTTPException(404, f"no video job {job_id}")
    return job


@router.post("", status_code=201)
def start_video(body: StartVideo, request: Request) -> dict[str, Any]:
    """Queue `mimickit video` of a clip (`clip`, on `char`) or of a policy (`run_id`, or `checkpoint`
    with its configs: by default those beside it), `seconds` long at `width`×`height`. It renders in
    `<runs-dir>/videos/<id>/`; `GET /api/videos/{id}` (or the stream's `videos` event) says when it is
    done, and `download` is then the MP4's URL."""
    studio = studio_of(request)
    s = studio.settings
    if sum(getattr(body, k) is not None for k in ("clip", "run_id", "checkpoint")) != 1:
        raise HTTPException(422, "give one of `clip`, `run_id` or `checkpoint`")
    size = {"seconds": body.seconds, "width": body.width, "height": body.height}
    if body.clip is not None:
        if any(getattr(body, k) is not None for k in CONFIG_KEYS):
            raise HTTPException(422, "`clip` takes `char`, not a checkpoint's configs")
        clip = confine(body.clip, s.readable_roots)
        return jobs_of(request).submit_clip(clip, _char_for(studio, body.clip, clip, body.char), **size).to_json()
    if body.char is not None:
        raise HTTPException(422, "`char` goes with `clip`; a checkpoint's character is its env config's")
    if body.run_id is not None:
        checkpoint = Path(studio.runs.get(body.run_id).out_dir) / CHECKPOINT  # 404 when there is no such run
        if not checkpoint.is_file():
            raise HTTPException(400, f"run {body.run_id} has no checkpoint yet ({CHECKPOINT})")
    else:
        checkpoint = confine(body.checkpoint, [*s.data_dirs, s.runs_dir])
    given = {k: confine(v, s.readable_roots) for k in CONFIG_KEYS if (v := getattr(body, k))}
    source = source_for_checkpoint(checkpoint, **given)  # MimicKitError (400) when no configs are beside it
    configs = {"env_config": source.env_config, "agent_config": source.agent_config}
    if source.engine_config is not None:
        configs["engine_config"] = source.engine_config
    if source.motion_file is not None:  # a shipped model's arg file: the clip it was trained on
        configs["motion_file"] = source.motion_file
    job = jobs_of(request).submit_policy(
        checkpoint, configs, run_id=body.run_id, data_dir=source.data_dir or s.data_dir, **size
    )
    return job.to_json()


@router.get("")
def list_videos(request: Request) -> list[dict[str, Any]]:
    """Every video job, newest first: this server's and those a server before it recorded."""
    return [j.to_json() for j in jobs_of(request).list()]


@router.get("/{job_id}")
def get_video(job_id: int, request: Request) -> dict[str, Any]:
    """`status` (queued, running, finished, failed, stopped), `error` (one line), and when finished
    `bytes` and `download` (the MP4's URL)."""
    return _job(request, job_id).to_json()


@router.post("/{job_id}/stop")
def stop_video(job_id: int, request: Request) -> dict[str, Any]:
    """Stop a queued job (it never starts) or a running one (its `mimickit video` process group is
    killed): status `stopped`. 409 when it had already ended."""
    job = _job(request, job_id)
    if not jobs_of(request).stop(job_id):
        raise HTTPException(409, f"video {job_id} has already ended ({job.status})")
    return job.to_json()


@router.get("/{job_id}/file")
def video_file(job_id: int, request: Request) -> FileResponse:
    """The finished job's MP4 (`video/mp4`), from its own folder only."""
    job = _job(request, job_id)
    if job.status != "finished":
        raise HTTPException(409, f"video {job_id} is {job.status}; its file comes when it has finished")
    path = confine(str(job.file), [job.folder])  # a symlink put in its place must not lead out of the folder
    return FileResponse(path, media_type="video/mp4", filename=f"{job.folder.name}-{VIDEO_FILE}")
