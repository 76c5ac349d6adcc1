"""The FastAPI application: `create_app(settings)` wires the library, the run manager, the viser scene
and the dashboard page into one ASGI app.

viser serves the 3D scene on its own port (it cannot be mounted inside FastAPI); the dashboard at `/`
embeds it in an iframe, so a user still opens one URL.
"""

from __future__ import annotations

import contextlib
import io
import threading
from collections.abc import AsyncIterator
from dataclasses import dataclass

import viser
from fastapi import FastAPI, Request
from fastapi.responses import FileResponse, JSONResponse
from fastapi.staticfiles import StaticFiles

from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_ROOT
from studio.api import library as library_api
from studio.api import runs as runs_api
from studio.api import scene as scene_api
from studio.library import Library
from studio.player import Player
from studio.player_gui import PlayerGui
from studio.registry import Registry
from studio.runs import RunError, RunManager
from studio.scene import StudioScene
from studio.security import PathError, TokenMiddleware
from studio.settings import Settings

WEB_DIR = PROJECT_ROOT / "web"
REGISTRY_FILE = "registry.sqlite"


@dataclass
class Studio:
    """The services behind the API; handlers reach it as `request.app.state.studio`."""

    settings: Settings
    library: Library
    registry: Registry
    runs: RunManager
    viser_server: viser.ViserServer | None = None
    scene: StudioScene | None = None
    player: Player | None = None

    @property
    def viser_port(self) -> int | None:
        return self.viser_server.get_port() if self.viser_server else None

    def close(self) -> None:
        if self.player:
            self.player.close()
        self.runs.close()
        if self.viser_server:
            with contextlib.redirect_stdout(io.StringIO()):  # viser prints "Server stopped"
                self.viser_server.stop()


def create_studio(settings: Settings) -> Studio:
    settings.resolved()
    settings.runs_dir.mkdir(parents=True, exist_ok=True)
    registry = Registry(settings.runs_dir / REGISTRY_FILE)
    studio = Studio(settings, Library(settings), registry, RunManager(settings, registry))
    if settings.start_viser:
        # viser prints its own banner; the studio prints one URL (the dashboard's) instead.
        with contextlib.redirect_stdout(io.StringIO()):
            studio.viser_server = viser.ViserServer(
                host=settings.host, port=settings.viser_port, label="MimicKit Studio", verbose=False
            )
        studio.scene = StudioScene(studio.viser_server)
        studio.player = Player(studio.scene)
        PlayerGui(studio.viser_server, studio.player)
    # Reading every clip once takes a second or two with a large data folder: do it before anyone asks.
    threading.Thread(target=studio.library.motions, name="library-warmup", daemon=True).start()
    return studio


def create_app(settings: Settings) -> FastAPI:
    studio = create_studio(settings)

    @contextlib.asynccontextmanager
    async def lifespan(_: FastAPI) -> AsyncIterator[None]:
        yield
        studio.close()

    app = FastAPI(
        title="MimicKit Studio",
        summary="Clips, characters, configs and training runs of MimicKit on MuJoCo; scene commands for the viewer.",
        version="0.1.0",
        lifespan=lifespan,
    )
    app.state.studio = studio
    if settings.needs_token:
        if not settings.token:
            raise ValueError(f"binding {settings.host} (not loopback) requires a token")
        app.add_middleware(TokenMiddleware, token=settings.token)

    for module in (library_api, scene_api, runs_api):
        app.include_router(module.router, prefix="/api")
    _add_error_handlers(app)

    @app.get("/", include_in_schema=False)
    def index() -> FileResponse:
        return FileResponse(WEB_DIR / "index.html", headers={"Cache-Control": "no-cache"})

    app.mount("/web", StaticFiles(directory=WEB_DIR), name="web")
    return app


def _add_error_handlers(app: FastAPI) -> None:
    """User mistakes become one message with a 4xx status, never a traceback."""

    @app.exception_handler(MimicKitError)
    async def _mimickit_error(_: Request, e: MimicKitError) -> JSONResponse:
        return JSONResponse({"detail": str(e)}, status_code=400)

    @app.exception_handler(PathError)
    async def _path_error(_: Request, e: PathError) -> JSONResponse:
        return JSONResponse({"detail": str(e)}, status_code=e.status)

    @app.exception_handler(RunError)
    async def _run_error(_: Request, e: RunError) -> JSONResponse:
        return JSONResponse({"detail": str(e)}, status_code=e.status)
