"""The FastAPI application: `create_app(settings)` wires the library, the run manager, the viser scene
and the dashboard page into one ASGI app.

viser serves the 3D scene on an internal loopback port (it cannot be mounted inside FastAPI); the
studio relays it under `/scene/` (`studio.scene_proxy`) and the dashboard at `/` embeds that in an
iframe, so a user opens one URL and every request, the scene's included, passes the same checks.
"""

from __future__ import annotations

import contextlib
import io
import logging
import threading
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from typing import Any

import torch
import viser
from fastapi import FastAPI, Request
from fastapi.responses import FileResponse, JSONResponse
from fastapi.staticfiles import StaticFiles

from mimickit.anim.motion import load_motion
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_WEB_DIR
from studio.api import checkpoints as checkpoints_api
from studio.api import compare as compare_api
from studio.api import evals as evals_api
from studio.api import library as library_api
from studio.api import need
from studio.api import runs as runs_api
from studio.api import scene as scene_api
from studio.api import stream as stream_api
from studio.api import sweeps as sweeps_api
from studio.api import videos as videos_api
from studio.clip_pose import pose_clip
from studio.library import Library
from studio.playable import Playable
from studio.player import Player
from studio.player_gui import SceneKeys
from studio.registry import Registry
from studio.rollout import Rollout, RolloutPlayer, RolloutSource
from studio.rollout_pair import RolloutPair
from studio.runs import RunError, RunManager
from studio.scene import StudioScene
from studio.scene_proxy import VISER_HOST, add_scene_proxy
from studio.scene_thread import SceneThread, SceneTimeout
from studio.security import HostPolicy, PathError, RequestGuard, confine
from studio.settings import Settings

LOG = logging.getLogger("studio")
WEB_DIR = PROJECT_WEB_DIR
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
    rollout: RolloutPlayer | None = None
    # The one thread that touches the scene, the clip player and the rollout (studio.scene_thread).
    scene_thread: SceneThread = field(default_factory=SceneThread)

    @property
    def viser_port(self) -> int | None:
        return self.viser_server.get_port() if self.viser_server else None

    @property
    def mode(self) -> str:
        return "rollout" if self.rollout is not None else "clip"

    def active(self) -> Playable | None:
        """What the scene commands drive: the rollout while one is loaded, else the clip player."""
        return self.rollout if self.rollout is not None else self.player

    def command(self, fn: Callable[[Playable], object]) -> dict[str, Any]:
        """`fn(active)` on the scene thread and the state after it (one command: nothing runs between);
        503 when there is no scene."""

        def run() -> dict[str, Any]:
            target = self.active()
            need(target, "the 3D scene")
            fn(target)
            return target.snapshot()

        return self.scene_thread.call(run)

    def load_rollout(
        self, source: RolloutSource, *, play: bool = True, partner: RolloutSource | None = None
    ) -> dict[str, Any]:
        """Build the rollout (MimicKitError when the checkpoint does not fit) and show it instead of
        the clip or the previous rollout; its state. `partner`: B of an A/B rollout (`source` is A);
        MimicKitError when the two cannot pair, before the rollout shown now ends."""
        built = _build_rollouts(source, partner)  # slow (envs, agents, checkpoints): off the scene thread
        rollout = built[0]
        try:
            pair = RolloutPair(*built) if partner is not None else None  # its first start: before the hand-over
        except BaseException:
            _close_all(built)
            raise

        def install() -> dict[str, Any]:
            self._end_rollout()
            if self.player:
                self.player.pause()
            self.rollout = RolloutPlayer(rollout, self.scene, self.scene_thread, play=play, pair=pair)
            self.scene_thread.drive(self.rollout)
            return self.rollout.snapshot()

        try:
            return self.scene_thread.call(install)
        except BaseException:
            if self.rollout is None or self.rollout.rollout is not rollout:
                _close_all(built)  # never shown: nothing else will close them
            raise

    def end_rollout(self) -> None:
        """Stop and forget the rollout (before a clip is loaded)."""
        self.scene_thread.call(self._end_rollout)

    def _end_rollout(self) -> None:
        rp, self.rollout = self.rollout, None
        self.scene_thread.drive(*([self.player] if self.player else []))
        if rp is None:
            return
        rp.close()
        if self.scene:
            self.scene.end_rollout()

    def close(self) -> None:
        with contextlib.suppress(Exception):  # a stuck scene thread must not keep the runs going
            self.end_rollout()
        self.scene_thread.close()
        self.runs.close()
        if self.viser_server:
            with contextlib.redirect_stdout(io.StringIO()):  # viser prints "Server stopped"
                self.viser_server.stop()


def _build_rollouts(source: RolloutSource, partner: RolloutSource | None) -> list[Rollout]:
    """A `Rollout` of `source`, and of `partner` when given; those built are closed when one fails."""
    sides = [("A", source), ("B", partner)] if partner is not None else [("", source)]
    built: list[Rollout] = []
    try:
        for side, s in sides:
            built.append(_build_side(side, s))
    except BaseException:
        _close_all(built)
        raise
    return built


def _build_side(side: str, source: RolloutSource) -> Rollout:
    """`Rollout(source)`; an A/B side's error (`side` "A" or "B") says which side, still in one line."""
    try:
        return Rollout(source)
    except Exception as e:
        if not side:
            raise
        detail = (str(e).strip().splitlines() or [""])[0]
        if not isinstance(e, MimicKitError):  # a broken config: as `roll_out` says it, with B's checkpoint
            detail = f"cannot roll out {source.checkpoint}: {type(e).__name__}: {detail}"
        raise MimicKitError(f"{side}: {detail}") from None


def _close_all(rollouts: list[Rollout]) -> None:
    for r in rollouts:
        r.close()


def create_studio(settings: Settings) -> Studio:
    settings.resolved()
    # The studio's own torch work (a rollout's policy, clip kinematics) is small: one thread, so that
    # torch's idle OpenMP workers do not spin on the cores the trainers need.
    torch.set_num_threads(1)
    settings.runs_dir.mkdir(parents=True, exist_ok=True)
    registry = Registry(settings.runs_dir / REGISTRY_FILE)
    studio = Studio(settings, Library(settings), registry, RunManager(settings, registry))
    if settings.start_viser:
        # viser prints its own banner; the studio prints one URL (the dashboard's) instead.
        with contextlib.redirect_stdout(io.StringIO()):
            # Loopback only, whatever --host says: browsers reach it through the studio's /scene/.
            studio.viser_server = viser.ViserServer(
                host=VISER_HOST, port=settings.viser_port, label="MimicKit Studio", verbose=False
            )
        studio.scene = StudioScene(studio.viser_server)
        studio.player = Player(studio.scene, studio.scene_thread)
        studio.scene_thread.call(studio.scene_thread.drive, studio.player)
        SceneKeys(studio.viser_server, active=studio.active)  # the page is the one control surface; keys queue
        if settings.startup_clip is not None:
            _play_startup_clip(studio)
    # Reading every clip once takes a second or two with a large data folder: do it before anyone asks.
    threading.Thread(target=studio.library.motions, name="library-warmup", daemon=True).start()
    return studio


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
    studio.player.load(pose_clip(clip, char), play=True)


def create_app(settings: Settings) -> FastAPI:
    studio = create_studio(settings)

    close_proxy = None

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        # The job lists at start: those a server before this one recorded (a job it died with: failed).
        jobs = [evals_api.jobs_in(app.state, settings), videos_api.jobs_in(app.state, settings)]
        yield
        if close_proxy is not None:
            await close_proxy()
        for queue in jobs:
            queue.close()  # a running job is killed; active jobs are recorded as failed (the server stopped)
        studio.close()

    app = FastAPI(
        title="MimicKit Studio",
        summary="Clips, characters, configs and training runs of MimicKit on MuJoCo; scene commands for the viewer.",
        version="0.1.0",
        lifespan=lifespan,
    )
    app.state.studio = studio
    if settings.needs_token and not settings.token:
        raise ValueError(f"binding {settings.host} (not loopback) requires a token")
    hosts = HostPolicy(settings.host, settings.allowed_hosts)
    app.add_middleware(RequestGuard, hosts=hosts, token=settings.token if settings.needs_token else None)

    routers = (library_api, scene_api, runs_api, checkpoints_api, compare_api, stream_api, evals_api, sweeps_api)
    for module in (*routers, videos_api):
        app.include_router(module.router, prefix="/api")
    _add_error_handlers(app)
    close_proxy = add_scene_proxy(app, lambda: studio.viser_port)

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

    @app.exception_handler(SceneTimeout)
    async def _scene_timeout(_: Request, e: SceneTimeout) -> JSONResponse:
        return JSONResponse({"detail": str(e)}, status_code=503)

    @app.exception_handler(RunError)
    async def _run_error(_: Request, e: RunError) -> JSONResponse:
        return JSONResponse({"detail": str(e)}, status_code=e.status)

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, e: Exception) -> JSONResponse:
        # The last resort: the traceback goes to the server's log, the page gets one line.
        LOG.error("%s %s failed", request.method, request.url.path, exc_info=e)
        first = (str(e).strip().splitlines() or [""])[0][:300]
        detail = f"internal error in {request.url.path}: {type(e).__name__}: {first} (traceback in the server log)"
        return JSONResponse({"detail": detail}, status_code=500)
