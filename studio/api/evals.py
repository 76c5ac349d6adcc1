"""Evaluation endpoints: `mimickit eval` of a checkpoint as a background job, its table, a rollout of
one row's clip, and stopping or deleting a job. `GET /api/stream`'s `evals` event pushes the job list."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from fastapi import APIRouter, HTTPException
from pydantic import Field

from mimickit.envs.env_builder import load_env_configs
from mimickit.learning.run_folder import AGENT_CONFIG_FILE, ENGINE_CONFIG_FILE, ENV_CONFIG_FILE
from studio.api import StudioDep
from studio.api.bodies import OneLineErrors, StrictBody
from studio.api.jobs import JobRoutes
from studio.api.runs import resolve_arg_file
from studio.api.scene import roll_out
from studio.api.sources import MAX_ID, checkpoint_of
from studio.jobs.evals import clip_env_config
from studio.runs.checkpoints import MOTION_FILE, configs_beside, configs_from_arg_file, job_file
from studio.security import confine

router = APIRouter(prefix="/evals", tags=["evals"], route_class=OneLineErrors)
MAX_EPISODES = 256
CLIP_SUFFIXES = (".pkl", ".yaml", ".yml")  # a clip or a dataset


class StartEval(StrictBody):
    run_id: int | None = Field(
        None, ge=0, le=MAX_ID, description="a run: its `model.pt` and the configs copied into its folder"
    )
    checkpoint: str | None = Field(None, description="a checkpoint file inside the data or runs folders")
    arg_file: str | None = Field(None, description="arg file naming the configs (default: those beside the checkpoint)")
    motion_file: str | None = Field(None, description="a clip or a dataset yaml (default: the env config's)")
    episodes: int = Field(4, ge=1, le=MAX_EPISODES, description="test episodes per clip")


class RollOutRow(StrictBody):
    row: int = Field(ge=0, description="index of the row in the job's `rows`")
    play: bool = True


ROUTES = JobRoutes(
    router,
    lambda studio: studio.evals,
    result="`rows` (one per clip: clip, weight, episodes, failed, mean_ep_len, full_length_frac (time-weighted), "
    "mean_return, pos_err_m, paper_pos_err_m, paper_dof_vel_err, steps, available_steps) and `mean`, the rows pooled",
)


@router.post("", status_code=201)
def start_eval(body: StartEval, studio: StudioDep) -> dict[str, Any]:
    """Queue `mimickit eval --json` of a run's checkpoint (`run_id`) or a checkpoint file, on each clip
    of `motion_file` (a clip or a dataset; default the env config's), `episodes` test episodes each.
    It runs as a subprocess in `<runs-dir>/evals/<id>/`; `GET /api/evals/{id}` (or the stream's
    `evals` event) says when it has ended."""
    s = studio.settings
    if (body.run_id is None) == (body.checkpoint is None):
        raise HTTPException(422, "give either `run_id` or `checkpoint`")
    checkpoint, _ = checkpoint_of(studio, body.run_id, body.checkpoint)
    arg_file = (
        job_file(resolve_arg_file(body.arg_file, s), body.arg_file, "arg_file", (".txt",)) if body.arg_file else None
    )
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
        load_env_configs(configs["env_config"], configs["engine_config"])  # what the tool would refuse: now
    motion = None
    if body.motion_file:
        motion = str(
            job_file(confine(body.motion_file, s.readable_roots), body.motion_file, "motion_file", CLIP_SUFFIXES)
        )
    if motion is None and configs is not None:
        motion = beside.get(MOTION_FILE)  # a shipped model's arg file: the clip it was trained on
    job = studio.evals.submit(
        checkpoint, arg_file=arg_file, configs=configs, motion_file=motion, episodes=body.episodes, run_id=body.run_id
    )
    return job.to_json()


@router.post("/{job_id}/rollout")
def roll_out_row(job_id: int, body: RollOutRow, studio: StudioDep) -> dict[str, Any]:
    """Roll the job's checkpoint out on one row's clip: its env config with `motion_file` set to that
    clip (written into the job's folder), then as `POST /api/scene/load_rollout`; the scene's state."""
    job = ROUTES.job(studio, job_id)
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
