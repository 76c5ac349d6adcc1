"""How the model's errors become HTTP answers: user mistakes are one message with a 4xx status, never a
traceback. A disk that refuses a write (full, read-only), from any route, is one line with 507 or 503
(`studio.disk`)."""

from __future__ import annotations

import logging
import sqlite3

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse

from mimickit.util.errors import MimicKitError
from studio.disk import DiskError, disk_error
from studio.runs.manager import RunError
from studio.scene.thread import SceneTimeout
from studio.security import PathError
from studio.services import SceneOff

LOG = logging.getLogger("studio")


def add_error_handlers(app: FastAPI) -> None:
    """The app's answer to each kind of error a route lets out."""

    @app.exception_handler(MimicKitError)
    async def _mimickit_error(_: Request, e: MimicKitError) -> JSONResponse:
        found = e if isinstance(e, DiskError) else disk_error(e)  # e.g. a checkpoint write on a full disk
        return JSONResponse({"detail": str(e)}, status_code=found.status if found else 400)

    @app.exception_handler(OSError)
    @app.exception_handler(sqlite3.Error)
    async def _disk_error(_: Request, e: Exception) -> JSONResponse:
        found = disk_error(e)
        if found is None:
            raise e  # not a disk's refusal: the last resort below answers it
        return JSONResponse({"detail": str(found)}, status_code=found.status)

    @app.exception_handler(PathError)
    async def _path_error(_: Request, e: PathError) -> JSONResponse:
        return JSONResponse({"detail": str(e)}, status_code=e.status)

    @app.exception_handler(SceneTimeout)
    @app.exception_handler(SceneOff)
    async def _scene_unavailable(_: Request, e: Exception) -> JSONResponse:
        return JSONResponse({"detail": str(e)}, status_code=503)

    @app.exception_handler(RunError)
    async def _run_error(_: Request, e: RunError) -> JSONResponse:
        return JSONResponse({"detail": str(e)}, status_code=e.status)

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, e: Exception) -> JSONResponse:
        # The last resort: the traceback goes to the server's log, the page gets one line.
        found = disk_error(e)  # a wrapper (RuntimeError, ...) raised while a disk refused a write
        if found is not None:
            return JSONResponse({"detail": str(found)}, status_code=found.status)
        LOG.error("%s %s failed", request.method, request.url.path, exc_info=e)
        first = (str(e).strip().splitlines() or [""])[0][:300]
        detail = f"internal error in {request.url.path}: {type(e).__name__}: {first} (traceback in the server log)"
        return JSONResponse({"detail": detail}, status_code=500)
