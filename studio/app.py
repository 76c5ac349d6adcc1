"""The FastAPI application: `create_app(settings)` wires the library, the run manager, the viser scene
and the dashboard page into one ASGI app.

viser serves the 3D scene on an internal loopback port (it cannot be mounted inside FastAPI); the
studio relays it under `/scene/` (`studio.scene.proxy`) and the dashboard at `/` embeds that in an
iframe, so a user opens one URL and every request, the scene's included, passes the same checks.
"""

from __future__ import annotations

import contextlib
import importlib
import io
import pkgutil
import threading
from collections.abc import AsyncIterator

import torch
from fastapi import APIRouter, FastAPI
from fastapi.responses import FileResponse
from fastapi.staticfiles import StaticFiles

from mimickit.anim.motion import load_motion
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_WEB_DIR
from studio.api import stream as stream_api
from studio.api.errors import add_error_handlers
from studio.jobs.kinds import JOB_KINDS
from studio.library import Library
from studio.runs.manager import RunManager
from studio.runs.registry import Registry
from studio.runs.run_list import RunList
from studio.scene.clip_pose import pose_clip
from studio.scene.player import Player
from studio.scene.player_gui import SceneKeys
from studio.scene.proxy import VISER_HOST, add_scene_proxy, guarded_viser_server
from studio.scene.view import StudioScene
from studio.security import HostPolicy, RequestGuard, confine
from studio.services import Studio
from studio.settings import Settings

WEB_DIR = PROJECT_WEB_DIR
REGISTRY_FILE = "registry.sqlite"


def create_studio(settings: Settings) -> Studio:
    settings.resolved()
    # The studio's own torch work (a rollout's policy, clip kinematics) is small: one thread, so that
    # torch's idle OpenMP workers do not spin on the cores the trainers need.
    torch.set_num_threads(1)
    settings.runs_dir.mkdir(parents=True, exist_ok=True)
    registry = Registry(settings.runs_dir / REGISTRY_FILE)
    # The job lists at start: those a server before this one recorded (a job it died with: failed).
    jobs = {kind.folder_name: kind(settings) for kind in JOB_KINDS}
    studio = Studio(settings, Library(settings), registry, RunManager(settings, registry), RunList(registry), jobs)
    if settings.start_viser:
        _start_scene(studio)
    # Reading every clip once takes a second or two with a large data folder: do it before anyone asks.
    threading.Thread(target=studio.library.motions, name="library-warmup", daemon=True).start()
    return studio


def _start_scene(studio: Studio) -> None:
    """The viser server, its drawing and the clip player; the startup clip playing, if one was named."""
    settings, scene = studio.settings, studio.scene
    # viser prints its own banner; the studio prints one URL (the dashboard's) instead.
    with contextlib.redirect_stdout(io.StringIO()):
        # Loopback only, whatever --host says, and only the relay's requests: browsers reach it
        # through the studio's /scene/.
        scene.viser_server = guarded_viser_server(
            host=VISER_HOST, port=settings.viser_port, label="MimicKit Studio", verbose=False
        )
    scene.view = StudioScene(scene.viser_server)
    scene.player = Player(scene.view, scene.thread)
    scene.thread.call(scene.thread.drive, scene.player)
    # A browser opening the 3D view wakes the scene thread: the clip is drawn at full rate again at once.
    scene.viser_server.on_client_connect(lambda _client: scene.thread.submit(lambda: None))
    SceneKeys(scene.viser_server, active=studio.active)  # the page is the one control surface; keys queue
    if settings.startup_clip is not None:
        _play_startup_clip(studio)


def _play_startup_clip(studio: Studio) -> None:
    """What a new user sees first: the character moving, not an empty grid."""
    settings = studio.settings
    clip, char = settings.startup_clip, settings.startup_char
    if not clip.is_file():
        raise MimicKitError(f"--clip {clip}: no such file")
    if char is None:
        guessed = studio.library.character_for_width(load_motion(clip).frame_dim, clip)
        if guessed is None:
            raise MimicKitError(f"--clip {clip}: no character in the data folders fits it; name one with --char")
        char = confine(guessed, settings.readable_roots)
    studio.scene.player.load(pose_clip(clip, char), play=True)


def api_routers() -> list[APIRouter]:
    """The router of every module of `studio/api/` that defines one (`router`), served under /api: a
    new panel's module is found without a list to extend."""
    import studio.api as api

    modules = (importlib.import_module(f"studio.api.{m.name}") for m in pkgutil.iter_modules(api.__path__))
    return [m.router for m in modules if isinstance(getattr(m, "router", None), APIRouter)]


def create_app(settings: Settings) -> FastAPI:
    studio = create_studio(settings)

    close_proxy = None

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        yield
        if close_proxy is not None:
            await close_proxy()
        studio.close()

    app = FastAPI(
        title="MimicKit Studio",
        summary="Clips, characters, configs and training runs of MimicKit on MuJoCo; scene commands for the viewer.",
        version="0.1.0",
        lifespan=lifespan,
    )
    app.state.studio = studio
    studio.live = stream_api.live_state(studio)
    if settings.needs_token and not settings.token:
        raise ValueError(f"binding {settings.host} (not loopback) requires a token")
    hosts = HostPolicy(settings.host, settings.allowed_hosts)
    app.add_middleware(RequestGuard, hosts=hosts, token=settings.token if settings.needs_token else None)

    for router in api_routers():
        app.include_router(router, prefix="/api")
    add_error_handlers(app)
    close_proxy = add_scene_proxy(app, lambda: studio.viser_port)

    @app.get("/", include_in_schema=False)
    def index() -> FileResponse:
        return FileResponse(WEB_DIR / "index.html", headers={"Cache-Control": "no-cache"})

    app.mount("/web", StaticFiles(directory=WEB_DIR), name="web")
    return app
