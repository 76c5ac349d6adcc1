"""What a request names to work on: the checkpoint of a run, or a checkpoint file."""

from __future__ import annotations

from pathlib import Path

from fastapi import HTTPException

from studio.runs.checkpoints import job_file
from studio.runs.manager import CHECKPOINT
from studio.security import confine
from studio.services import Studio

MAX_ID = 2**62  # ids are SQLite integers (64-bit signed): a larger one names nothing


def checkpoint_of(studio: Studio, run_id: int | None, checkpoint: str | None) -> tuple[Path, str | None]:
    """A run's `model.pt` and the run's name (404 when there is no such run, 400 before its first
    checkpoint), or `checkpoint` confined to the data and runs folders and None (one line when it is not a
    `.pt` file)."""
    s = studio.settings
    if run_id is None:
        return job_file(confine(checkpoint, [*s.data_dirs, s.runs_dir]), checkpoint, "checkpoint", (".pt",)), None
    run = studio.runs.get(run_id)
    path = Path(run.out_dir) / CHECKPOINT
    if not path.is_file():
        raise HTTPException(400, f"run {run.id} has no checkpoint yet ({CHECKPOINT} appears after its first iteration)")
    return path, run.name
