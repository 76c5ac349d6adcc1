"""Evaluation endpoints: `mimickit eval` of a checkpoint as a background job, its table, a rollout of
one row's clip, and stopping or deleting a job. `GET /api/stream`'s `evals` event pushes the job list."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

from fastapi import APIRouter, HTTPException, Request, Response
from pydantic import Field

from mimickit.run_folder import AGENT_CONFIG_FILE, ENGINE_CONFIG_FILE, ENV_CONFIG_FILE
from studio.api import studio_of
from studio.api.bodies import OneLineErrors, StrictBody
from studio.api.runs import resolve_arg_file
from studio.api.scene import roll_out
from studio.checkpoints import MOTION_FILE, configs_beside, configs_from_arg_file
from studio.evals import ACTIVE, EvalJob, EvalJobs, clip_env_config
from studio.runs import CHECKPOINT
from studio.security import confine
from studio.settings import Settings

router = APIRouter(prefix="/evals", tags=["evals"], route_class=OneLineErrors)
MAX_EPISODES = 256
_jobs_lock = threading.Lock()


class StartEval(StrictBody):
    run_id: int | None = Field(None, description="a run: its `model.pt` and the configs copied into its folder")
    checkpoint: str | None = Field(None, description="a checkpoint file inside the data or runs folders")
    arg_file: str | None = Field(None, description="arg file naming the configs (default: those beside the checkpoint)")
    motion_file: str | None = Field(None, description="a clip or a dataset yaml (default: the env config's)")
    episodes: int = Field(4, ge=1, le=MAX_EPISODES, description="test episodes per clip")


class RollOutRow(StrictBody):
    row: int = Field(ge=0, description="index of the row in the job's `rows`")
    play: bool = True


def jobs_in(state: Any, settings: Settings) -> EvalJobs:
    """The app's eval jobs (`state.evals`), made on first use: the server makes them at start-up, listing
    the jobs recorded under `<runs-dir>/evals/` (their worker thread starts with them)."""
    with _jobs_lock:
        if getattr(state, "evals", None) is None:
            state.evals = EvalJobs(settings)
        return state.evals


def jobs_of(request: Request) -> EvalJobs:
    return jobs_in(request.app.state, studio_of(request).settings)


def _job(request: Request, job_id: int) -> EvalJob:
    job = jobs_of(request).get(job_id)
    if job is None:
        raise HTTPException(404, f"no eval job {job_id}")
    return job


@router.post("", status_code=201)
def start_eval(body: StartEval, request: Request) -> dict[str, Any]:
    """Queue `mimickit eval --json` of a run's checkpoint (`run_id`) or a checkpoint file, on each clip
    of `motion_file` (a clip or a dataset; default the env config's), `episodes` test episodes each.
    It runs as a subprocess in `<runs-dir>/evals/<id>/`; `GET /api/evals/{id}` (or the stream's
    `evals` event) says when it has ended."""
    studio = studio_of(request)
    s = studio.settings
    if (body.run_id is None) == (body.checkpoint is None):
        raise HTTPException(422, "give either `run_id` or `checkpoint`")
    if body.run_id is not None:
        checkpoint = Path(studio.runs.get(body.run_id).out_dir) / CHECKPOINT  # 404 when there is no such run
        if not checkpoint.is_file():
            raise HTTPException(400, f"run {body.run_id} has no checkpoint yet ({CHECKPOINT})")
    else:
        checkpoint = confine(body.checkpoint, [*s.data_dirs, s.runs_dir])
    arg_file = resolve_arg_file(body.arg_file, s) if body.arg_file else None
    configs = None
    if arg_file is None:
        beside = configs_beside(checkpoint)
        if ENV_CONFIG_FILE not in beside or AGENT_CONFIG_FILE not in beside:
            raise HTTPException(400, f"{checkpoint}: no env and agent configs beside it; give `arg_file`")
        configs = {
            "env_config": beside[ENV_CONFIG_FILE],
            "agent_config": beside[AGENT_CONFIG_FILE],
            "engine_config": beside.get(ENGINE_CONFIG_FILE),
        }
    motion = str(confine(body.motion_file, s.readable_roots)) if body.motion_file else None
    if motion is None and configs is not None:
        motion = beside.get(MOTION_FILE)  # a shipped model's arg file: the clip it was trained on
    job = jobs_of(request).submit(
        checkpoint, arg_file=arg_file, configs=configs, motion_file=motion, episodes=body.episodes, run_id=body.run_id
    )
    return job.to_json()


@router.get("")
def list_evals(request: Request) -> list[dict[str, Any]]:
    """Every eval job, newest first: this server's and those a server before it recorded."""
    return [j.to_json() for j in jobs_of(request).list()]


@router.get("/{job_id}")
def get_eval(job_id: int, request: Request) -> dict[str, Any]:
    """`status` (queued, running, finished, failed, stopped), `error` (one line; a job the server stopped
    with: `the server stopped while the job ran; ...`) and, when finished, `rows`
    (one per clip: clip, weight, episodes, mean_ep_len, full_length_frac, mean_return, pos_err_m,
    paper_pos_err_m, paper_dof_vel_err) and their episode-weighted `mean`."""
    return _job(request, job_id).to_json()


@router.post("/{job_id}/stop")
def stop_eval(job_id: int, request: Request) -> dict[str, Any]:
    """Stop a queued job (it never starts) or a running one (its `mimickit eval` process group is
    killed): status `stopped`. 409 when it had already ended."""
    job = _job(request, job_id)
    if not jobs_of(request).stop(job_id):
        raise HTTPException(409, f"eval {job_id} has already ended ({job.status})")
    return job.to_json()


@router.delete("/{job_id}", status_code=204)
def delete_eval(job_id: int, request: Request) -> Response:
    """Remove an ended job from the list and delete its folder (`<runs-dir>/evals/<id>/`). 409 while it
    is queued or running: stop it first."""
    job = _job(request, job_id)
    if job.status in ACTIVE or not jobs_of(request).remove(job_id):
        raise HTTPException(409, f"eval {job_id} is {job.status}; stop it first")
    return Response(status_code=204)


@router.post("/{job_id}/rollout")
def roll_out_row(job_id: int, body: RollOutRow, request: Request) -> dict[str, Any]:
    """Roll the job's checkpoint out on one row's clip: its env config with `motion_file` set to that
    clip (written into the job's folder), then as `POST /api/scene/load_rollout`; the scene's state."""
    studio = studio_of(request)
    job = _job(request, job_id)
    if job.status != "finished":
        raise HTTPException(409, f"eval {job_id} is {job.status}; its rows come when it has finished")
    if body.row >= len(job.rows):
        raise HTTPException(422, f"row: eval {job_id} has {len(job.rows)} rows")
    clip = confine(str(job.rows[body.row]["clip"]), studio.settings.readable_roots)
    found = configs_from_arg_file(job.arg_file, data_dir=studio.settings.data_dir)  # type: ignore[arg-type]
    if ENV_CONFIG_FILE not in found:
        raise HTTPException(400, f"{job.arg_file}: names no env config")
    env = clip_env_config(Path(found[ENV_CONFIG_FILE]), clip, job.folder / f"row{body.row}_env_config.yaml")
    configs = {
        "env_config": env,
        "agent_config": Path(found[AGENT_CONFIG_FILE]) if AGENT_CONFIG_FILE in found else None,
        "engine_config": Path(found[ENGINE_CONFIG_FILE]) if ENGINE_CONFIG_FILE in found else None,
    }
    return roll_out(studio, job.checkpoint, configs, play=body.play, run_id=job.run_id)
