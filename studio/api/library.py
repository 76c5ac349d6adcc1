"""Library endpoints: health, clips, characters, configs and arg files, clip upload."""

from __future__ import annotations

import re
from typing import Any

from fastapi import APIRouter, HTTPException, Query, Request
from fastapi.responses import JSONResponse
from starlette.concurrency import run_in_threadpool

from mimickit.util.paths import atomic_write_bytes
from studio.api import studio_of
from studio.api.bodies import OneLineErrors
from studio.parsing import read_motion_bytes

router = APIRouter(tags=["library"], route_class=OneLineErrors)


@router.get("/health")
def health(request: Request) -> dict[str, Any]:
    """Liveness, the viser port the page embeds, and where the studio looks for files."""
    studio = studio_of(request)
    s = studio.settings
    return {
        "status": "ok",
        "viser_port": studio.viser_port,
        "scene_url": "/scene/" if studio.viser_port else None,
        "data_dirs": [str(d) for d in s.data_dirs],
        "runs_dir": str(s.runs_dir),
        "max_concurrent_runs": s.max_concurrent_runs,
        "token_required": s.needs_token,
    }


@router.get("/motions", response_class=JSONResponse)
def motions(request: Request) -> JSONResponse:
    """Every clip in the data folders' `motions/` and in uploads: fps, loop mode, frames, duration,
    frame width and the character guessed from it."""
    # Plain JSON data already: JSONResponse skips FastAPI's per-item encoder (slow for 300 clips).
    return JSONResponse(studio_of(request).library.motions())


@router.get("/characters")
def characters(request: Request) -> list[dict[str, Any]]:
    """MJCF characters under `assets/`: bodies, DoFs and the clip frame width they take."""
    return studio_of(request).library.characters()


@router.get("/configs")
def configs(request: Request) -> dict[str, list[dict[str, Any]]]:
    """Env, agent and engine yamls, dataset yamls and arg files."""
    return studio_of(request).library.configs()


@router.post("/motions/upload", status_code=201)
async def upload_motion(
    request: Request, filename: str = Query(..., description="name to save the clip as")
) -> dict[str, Any]:
    """Upload a `.pkl` clip as the raw request body. It is read through the restricted unpickler and
    validated before anything is written; it lands in `<runs-dir>/uploads/`."""
    studio = studio_of(request)
    limit = studio.settings.upload_limit_bytes
    declared = request.headers.get("content-length", "")
    if declared.isdigit() and int(declared) > limit:  # refused before a byte is read
        raise HTTPException(413, f"a clip may be at most {limit} bytes, this one is {declared}")
    body = bytearray()
    async for chunk in request.stream():
        body += chunk
        if len(body) > limit:
            raise HTTPException(413, f"a clip may be at most {limit} bytes")
    # Parsed in a worker thread (a child process with a budget, when the guarded loader is there):
    # a hostile clip must not stall the other requests.
    motion = await run_in_threadpool(read_motion_bytes, bytes(body), source=upload_stem(filename) + ".pkl")
    folder = studio.settings.uploads_dir
    stem = upload_stem(filename)
    target = folder / f"{stem}.pkl"
    n = 1
    while target.exists():
        n += 1
        target = folder / f"{stem}_{n}.pkl"
    atomic_write_bytes(target, bytes(body))  # the bytes as given: byte-compatible with MimicKit
    studio.library.invalidate()
    return {"path": str(target), "num_frames": motion.num_frames, "fps": motion.fps, "frame_dim": motion.frame_dim}


MAX_STEM_CHARS = 100  # well under a file system's 255-byte name limit, with `_N.pkl` after it


def upload_stem(filename: str) -> str:
    """A safe file stem for an uploaded clip: the last path part, odd characters as `_`, at most
    `MAX_STEM_CHARS` characters; `clip` when nothing is left."""
    base = filename.replace("\\", "/").rsplit("/", 1)[-1]
    stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", base).removesuffix(".pkl").strip("._")
    return stem[:MAX_STEM_CHARS].strip("._") or "clip"
