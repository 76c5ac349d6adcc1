"""MP4 export endpoints: `mimickit video` of a clip or of a checkpoint's policy as a background job,
its status, stopping it, and the video. `GET /api/stream`'s `videos` event pushes the job list."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, HTTPException
from fastapi.responses import FileResponse
from pydantic import Field, field_validator

from mimickit.envs.env_builder import load_env_configs
from studio.api import StudioDep
from studio.api.bodies import OneLineErrors, StrictBody
from studio.api.jobs import JobRoutes
from studio.api.scene import _char_for
from studio.api.sources import MAX_ID, checkpoint_of
from studio.jobs.videos import VIDEO_FILE
from studio.runs.checkpoints import job_file
from studio.scene.rollout import source_for_checkpoint
from studio.security import confine

router = APIRouter(prefix="/videos", tags=["videos"], route_class=OneLineErrors)
MAX_SECONDS = 60.0
MAX_WIDTH, MAX_HEIGHT = 1920, 1080
CONFIG_KEYS = ("env_config", "agent_config", "engine_config")
YAML = (".yaml", ".yml")


class StartVideo(StrictBody):
    clip: str | None = Field(None, description="a clip (.pkl) to play kinematically")
    char: str | None = Field(None, description="the clip's MJCF character (default: guessed from its frame width)")
    run_id: int | None = Field(
        None, ge=0, le=MAX_ID, description="a run: its `model.pt` and the configs copied into its folder"
    )
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


ROUTES = JobRoutes(router, lambda studio: studio.videos, result="`bytes` and `download` (the MP4's URL)")


@router.post("", status_code=201)
def start_video(body: StartVideo, studio: StudioDep) -> dict[str, Any]:
    """Queue `mimickit video` of a clip (`clip`, on `char`) or of a policy (`run_id`, or `checkpoint`
    with its configs: by default those beside it), `seconds` long at `width`×`height`. It renders in
    `<runs-dir>/videos/<id>/`; `GET /api/videos/{id}` (or the stream's `videos` event) says when it is
    done, and `download` is then the MP4's URL."""
    s = studio.settings
    if sum(getattr(body, k) is not None for k in ("clip", "run_id", "checkpoint")) != 1:
        raise HTTPException(422, "give one of `clip`, `run_id` or `checkpoint`")
    size = {"seconds": body.seconds, "width": body.width, "height": body.height}
    if body.clip is not None:
        if any(getattr(body, k) is not None for k in CONFIG_KEYS):
            raise HTTPException(422, "`clip` takes `char`, not a checkpoint's configs")
        clip = job_file(confine(body.clip, s.readable_roots), body.clip, "clip", (".pkl",))
        char = _char_for(studio, body.clip, clip, body.char)
        char = job_file(char, body.char or str(char), "char", (".xml",))
        return studio.videos.submit_clip(clip, char, **size).to_json()
    if body.char is not None:
        raise HTTPException(422, "`char` goes with `clip`; a checkpoint's character is its env config's")
    checkpoint, _ = checkpoint_of(studio, body.run_id, body.checkpoint)
    given = {k: job_file(confine(v, s.readable_roots), v, k, YAML) for k in CONFIG_KEYS if (v := getattr(body, k))}
    source = source_for_checkpoint(checkpoint, **given)  # MimicKitError (400) when no configs are beside it
    load_env_configs(source.env_config, source.engine_config)  # no engine config anywhere: refused now, not later
    configs = {"env_config": source.env_config, "agent_config": source.agent_config}
    if source.engine_config is not None:
        configs["engine_config"] = source.engine_config
    if source.motion_file is not None:  # a shipped model's arg file: the clip it was trained on
        configs["motion_file"] = source.motion_file
    job = studio.videos.submit_policy(
        checkpoint, configs, run_id=body.run_id, data_dir=source.data_dir or s.data_dir, **size
    )
    return job.to_json()


@router.get("/{job_id}/file")
def video_file(job_id: int, studio: StudioDep) -> FileResponse:
    """The finished job's MP4 (`video/mp4`), from its own folder only."""
    job = ROUTES.job(studio, job_id)
    if job.status != "finished":
        raise HTTPException(409, f"video {job_id} is {job.status}; its file comes when it has finished")
    path = confine(str(job.file), [job.folder])  # a symlink put in its place must not lead out of the folder
    return FileResponse(path, media_type="video/mp4", filename=f"{job.folder.name}-{VIDEO_FILE}")
