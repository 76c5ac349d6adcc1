"""Scene commands: load a clip on a character, play, pause, step, seek, and the player's state."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, HTTPException, Request
from pydantic import BaseModel, Field

from studio.api import need, studio_of
from studio.clip_pose import pose_clip
from studio.player import Player
from studio.security import confine

router = APIRouter(prefix="/scene", tags=["scene"])


class LoadClip(BaseModel):
    path: str = Field(description="a clip: `data/motions/...` or a path inside the data/runs folders")
    char: str | None = Field(None, description="an MJCF character; guessed from the clip's frame width if absent")
    play: bool = Field(False, description="start playing at once")


class Step(BaseModel):
    frames: int = 1


class Seek(BaseModel):
    frame: int | None = None
    time: float | None = Field(None, description="seconds; used when `frame` is absent")


class Configure(BaseModel):
    speed: float | None = None
    loop: bool | None = None
    follow: bool | None = Field(None, description="camera follows the character")


def _player(request: Request) -> Player:
    player = studio_of(request).player
    need(player, "the 3D scene")
    return player


@router.post("/load_clip")
def load_clip(body: LoadClip, request: Request) -> dict[str, Any]:
    """Pose the clip on its character and show frame 0 (the character is rebuilt only if it changes)."""
    studio = studio_of(request)
    player = _player(request)
    roots = studio.settings.readable_roots
    clip = confine(body.path, roots)
    char_path = body.char
    if char_path is None:
        info = next((m for m in studio.library.motions() if m["path"] in (body.path, str(clip))), None)
        frame_dim = info.get("frame_dim") if info else None
        char_path = studio.library.character_for_width(frame_dim, clip) if frame_dim else None
        if char_path is None:
            raise HTTPException(400, f"{body.path}: no character fits this clip; name one with `char`")
    pose = pose_clip(clip, confine(char_path, roots))
    player.load(pose, play=body.play)
    return player.snapshot()


@router.post("/play")
def play(request: Request) -> dict[str, Any]:
    player = _player(request)
    player.play()
    return player.snapshot()


@router.post("/pause")
def pause(request: Request) -> dict[str, Any]:
    player = _player(request)
    player.pause()
    return player.snapshot()


@router.post("/toggle")
def toggle(request: Request) -> dict[str, Any]:
    """Play/pause, as the Enter key."""
    player = _player(request)
    player.toggle()
    return player.snapshot()


@router.post("/step")
def step(request: Request, body: Step | None = None) -> dict[str, Any]:
    """Pause and move by `frames` (default 1, as the Space key)."""
    player = _player(request)
    player.step((body or Step()).frames)
    return player.snapshot()


@router.post("/seek")
def seek(body: Seek, request: Request) -> dict[str, Any]:
    player = _player(request)
    if body.frame is None and body.time is None:
        raise HTTPException(422, "give `frame` or `time`")
    player.seek(frame=body.frame, time_s=body.time)
    return player.snapshot()


@router.post("/configure")
def configure(body: Configure, request: Request) -> dict[str, Any]:
    """Speed, loop and camera follow."""
    player = _player(request)
    player.configure(speed=body.speed, loop=body.loop, follow=body.follow)
    return player.snapshot()


@router.get("/state")
def state(request: Request) -> dict[str, Any]:
    """Clip, character, frame, time, playing, speed, loop, follow, scene updates sent, the drawn
    root position and which feet touch the ground."""
    return _player(request).snapshot()
