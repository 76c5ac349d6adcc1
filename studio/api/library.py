"""Library endpoints: health, clips, characters (and their default pose), configs and arg files (and
one file's text), clip upload and deletion."""

from __future__ import annotations

import re
from typing import Any

from fastapi import APIRouter, HTTPException, Query, Request, Response
from fastapi.responses import JSONResponse
from starlette.concurrency import run_in_threadpool

from mimickit.util.paths import atomic_write_bytes
from studio.api import studio_of
from studio.api.bodies import OneLineErrors
from studio.api.runs import resolve_arg_file
from studio.disk import disk_error
from studio.parsing import read_motion_bytes
from studio.security import PathError, confine

router = APIRouter(tags=["library"], route_class=OneLineErrors)


@router.get("/health")
async def health(request: Request) -> dict[str, Any]:  # settings only: no worker thread needed
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
async def motions(request: Request) -> Response:
    """Every clip in the data folders' `motions/` and in uploads: fps, loop mode, frames, duration,
    frame width and the character guessed from it."""
    library = studio_of(request).library
    # The memoised listing is served from the event loop (its JSON encoded once per listing); only the
    # first scan goes to a worker thread. Plain JSON data already: no FastAPI per-item encoder.
    listed = library.motions_listed()
    if listed is None:
        listed = await run_in_threadpool(library.motions)
    return Response(_encoded(listed), media_type="application/json")


_last_encoded: tuple[list, bytes] | None = None


def _encoded(listing: list[dict[str, Any]]) -> bytes:
    """`listing` as JSON bytes, encoded again only when the library made a new listing (a new list)."""
    global _last_encoded
    last = _last_encoded
    if last is None or last[0] is not listing:
        last = _last_encoded = (listing, JSONResponse(listing).body)
    return last[1]


@router.get("/characters")
def characters(request: Request) -> list[dict[str, Any]]:
    """MJCF characters under `assets/`: bodies, DoFs and the clip frame width they take."""
    return studio_of(request).library.characters()


@router.get("/characters/pose")
def character_pose(
    request: Request, path: str = Query(..., description="an MJCF under a data folder's assets/")
) -> dict[str, Any]:
    """The character in its default pose (every DoF 0, standing on the ground): each body's parent,
    world position and rotation, and its joint (type, DoF columns, axis, limits). Show it in the
    scene with `POST /api/scene/show_character`."""
    studio = studio_of(request)
    return studio.library.character_pose(character_path(studio, path))


def character_path(studio: Any, path: str) -> Any:
    """`path` confined to the data folders' `assets/` and an `.xml` file (PathError otherwise)."""
    found = confine(path, studio.settings.readable_roots)
    assets = [(d / "assets").resolve() for d in studio.settings.data_dirs]
    if found.suffix != ".xml" or not any(found.is_relative_to(a) for a in assets):
        raise PathError(f"not a character (an MJCF .xml under a data folder's assets/): {path}", 403)
    return found


@router.get("/configs")
def configs(request: Request) -> dict[str, list[dict[str, Any]]]:
    """Env, agent and engine yamls, dataset yamls and arg files; each dataset's clips with their
    weights, shares of the total weight and whether each file is there."""
    return studio_of(request).library.configs()


@router.get("/configs/file")
def config_file(request: Request, path: str = Query(..., description="an arg file or a config yaml")) -> dict[str, Any]:
    """One arg file, env/agent/engine yaml or dataset yaml, read-only: `text`, `kind` and, for an arg
    file or an env yaml, `trains`: the env config, the clip or dataset (`motion_file`) and the
    character (`char_file`) it names, each with `resolved` and `exists`. Only files in the args
    folders and the data folders' `envs/`, `agents/`, `engines/`, `datasets/` (403 otherwise)."""
    studio = studio_of(request)
    return studio.library.config_file(resolve_arg_file(path, studio.settings))


@router.post("/motions/upload", status_code=201)
async def upload_motion(
    request: Request, response: Response, filename: str = Query(..., description="name to save the clip as")
) -> dict[str, Any]:
    """Upload a `.pkl` clip as the raw request body. It is read through the restricted unpickler and
    validated before anything is written; it lands in `<runs-dir>/uploads/` (201). The same bytes
    uploaded again return the upload already there (200, `duplicate: true`)."""
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
    data = bytes(body)
    existing = await run_in_threadpool(studio.library.upload_of, data)
    if existing is not None:  # the same bytes again: the upload already there, not a `_2` copy
        response.status_code = 200
        info = await run_in_threadpool(studio.library.motion_info, existing)
        keys = ("num_frames", "fps", "frame_dim")
        return {"path": str(existing), **{k: info.get(k) for k in keys}, "duplicate": True}
    motion = await run_in_threadpool(read_motion_bytes, data, source=upload_stem(filename) + ".pkl")
    folder = studio.settings.uploads_dir
    stem = upload_stem(filename)
    target = folder / f"{stem}.pkl"
    n = 1
    while target.exists():
        n += 1
        target = folder / f"{stem}_{n}.pkl"
    try:
        atomic_write_bytes(target, data)  # the bytes as given: byte-compatible with MimicKit
    except OSError as e:  # a full or read-only disk: one line naming the upload (507 / 503), not its temp file
        found = disk_error(e, target)
        if found is None:
            raise
        raise found from e
    studio.library.invalidate()
    return {
        "path": str(target),
        "num_frames": motion.num_frames,
        "fps": motion.fps,
        "frame_dim": motion.frame_dim,
        "duplicate": False,
    }


@router.delete("/motions/upload", status_code=204)
def delete_upload(request: Request, path: str = Query(..., description="an uploaded clip, as listed")) -> Response:
    """Remove an uploaded clip. Only `.pkl` files directly in `<runs-dir>/uploads/` (403 for a data
    folder's clip, a path out of the uploads folder or a symlink; 404 when it is not there)."""
    studio_of(request).library.delete_upload(path)
    return Response(status_code=204)


MAX_STEM_CHARS = 100  # well under a file system's 255-byte name limit, with `_N.pkl` after it


def upload_stem(filename: str) -> str:
    """A safe file stem for an uploaded clip: the last path part, odd characters as `_`, at most
    `MAX_STEM_CHARS` characters; `clip` when nothing is left."""
    base = filename.replace("\\", "/").rsplit("/", 1)[-1]
    stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", base).removesuffix(".pkl").strip("._")
    return stem[:MAX_STEM_CHARS].strip("._") or "clip"
