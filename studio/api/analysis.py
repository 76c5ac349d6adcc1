"""Clip analysis of what the scene shows (the page's Analysis box): per-frame joint angles and
velocities, the root path and foot contacts of the clip, or of the rollout's recorded history beside
its reference (`studio/scene/analysis.py`)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, HTTPException, Query

from studio.api import StudioDep, need
from studio.api.bodies import OneLineErrors
from studio.scene.analysis import MAX_JOINTS, analyse_clip, analyse_rollout, record
from studio.scene.clip_pose import ClipPose
from studio.services import Studio

router = APIRouter(prefix="/scene", tags=["scene"], route_class=OneLineErrors)


@router.get("/analysis")
def analysis(
    studio: StudioDep,
    joints: str | None = Query(
        None, description=f"joint names, comma-separated (at most {MAX_JOINTS}); default: the first hinges"
    ),
) -> dict[str, Any]:
    """Per-frame arrays of the clip shown (every frame) or the rollout (its recorded history; an A/B
    rollout: A): `time`, the root path, each picked joint's angle and angular velocity, foot contacts;
    a rollout's reference (its ghost) beside the character as `ref`. 400 naming an unknown joint; 409
    when nothing is loaded. Synchronous: FastAPI runs it in a worker thread, off the event loop."""
    names = [n.strip() for n in joints.split(",") if n.strip()] if joints else None
    need(studio.scene.player, "the 3D scene")
    shown = studio.scene.thread.call(lambda: _shown(studio))  # copies, taken where the scene lives
    if shown is None:
        raise HTTPException(409, "nothing to analyse: load a clip or a rollout")
    if isinstance(shown, ClipPose):
        return analyse_clip(shown, names)
    return analyse_rollout(shown, names)


def _shown(studio: Studio) -> Any:
    """On the scene thread: the rollout's recorded history (copied), else the clip's pose, else None."""
    if studio.scene.rollout is not None:
        return record(studio.scene.rollout.rollout)
    return studio.scene.player.pose
