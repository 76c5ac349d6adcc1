"""The studio's services, each a typed handle on one `Studio`: the library, the run registry and
manager, the 3D scene, the eval and video job queues and what `GET /api/stream` pushes. `studio.app`
makes one per server; the routers reach it through `studio.api.StudioDep`. What goes wrong here is the
model's own error (`SceneOff`, `SceneTimeout`, `MimicKitError`); only `studio.api` turns it into HTTP.
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import viser

from mimickit.util.errors import MimicKitError
from studio.jobs.evals import EvalJobs
from studio.jobs.queue import JobQueue
from studio.jobs.videos import VideoJobs
from studio.library import Library
from studio.live_state import LiveState
from studio.runs.manager import RunManager
from studio.runs.registry import Registry
from studio.runs.run_list import RunList
from studio.scene.playable import Playable
from studio.scene.player import Player
from studio.scene.rollout import LAYOUTS, Rollout, RolloutPlayer, RolloutSource
from studio.scene.rollout_pair import RolloutPair
from studio.scene.thread import SceneThread
from studio.scene.view import StudioScene
from studio.settings import Settings


class SceneOff(Exception):
    """A scene command in a server that runs without the 3D scene (e.g. API-only tests)."""

    def __init__(self) -> None:
        super().__init__("the 3D scene is not running in this server")


@dataclass
class Scene:
    """The 3D scene's parts; all but `thread` are None in a server without viser."""

    viser_server: viser.ViserServer | None = None
    view: StudioScene | None = None
    player: Player | None = None
    rollout: RolloutPlayer | None = None
    # The one thread that touches the view, the clip player and the rollout (studio.scene.thread).
    thread: SceneThread = field(default_factory=SceneThread)


@dataclass
class Studio:
    """The services behind the API."""

    settings: Settings
    library: Library
    registry: Registry
    runs: RunManager
    run_list: RunList  # what the API and the stream list of the runs
    jobs: dict[str, JobQueue]  # every kind's queue by its folder name (`studio.jobs.kinds.JOB_KINDS`)
    scene: Scene = field(default_factory=Scene)
    live: LiveState | None = None  # what the stream pushes: its readers are the API's (`studio.api.stream`)

    @property
    def evals(self) -> EvalJobs:
        return self.jobs[EvalJobs.folder_name]  # type: ignore[return-value]

    @property
    def videos(self) -> VideoJobs:
        return self.jobs[VideoJobs.folder_name]  # type: ignore[return-value]

    @property
    def viser_port(self) -> int | None:
        return self.scene.viser_server.get_port() if self.scene.viser_server else None

    def active(self) -> Playable | None:
        """What the scene commands drive: the rollout while one is loaded, else the clip player."""
        return self.scene.rollout if self.scene.rollout is not None else self.scene.player

    def command(self, fn: Callable[[Playable], object]) -> dict[str, Any]:
        """`fn(active)` on the scene thread and the state after it (one command: nothing runs between);
        SceneOff when there is no scene."""

        def run() -> dict[str, Any]:
            target = self.active()
            if target is None:
                raise SceneOff
            fn(target)
            return target.snapshot()

        return self.scene.thread.call(run)

    def load_rollout(
        self,
        source: RolloutSource,
        *,
        play: bool = True,
        partner: RolloutSource | None = None,
        num_envs: int = 1,
        layout: str = "grid",
    ) -> dict[str, Any]:
        """Build the rollout (MimicKitError when the checkpoint does not fit) and show it instead of
        the clip or the previous rollout; its state. `partner`: B of an A/B rollout (`source` is A);
        MimicKitError when the two cannot pair, before the rollout shown now ends. `num_envs` envs of one
        policy, drawn as `layout` (`RolloutPlayer`); an A/B rollout has one env a side."""
        if partner is not None and num_envs != 1:
            raise MimicKitError(f"an A/B rollout runs one env a side, not {num_envs}: give num_envs 1 or no B")
        if layout not in LAYOUTS:
            raise MimicKitError(f"layout must be one of {', '.join(LAYOUTS)}, not {layout[:40]!r}")
        built = _build_rollouts(source, partner, num_envs)  # slow (envs, agents, checkpoints): off the scene thread
        rollout = built[0]
        try:
            pair = RolloutPair(*built) if partner is not None else None  # its first start: before the hand-over
        except BaseException:
            _close_all(built)
            raise
        scene = self.scene

        def install() -> dict[str, Any]:
            self._end_rollout()
            if scene.player:
                scene.player.pause()
            scene.rollout = RolloutPlayer(rollout, scene.view, scene.thread, play=play, pair=pair, layout=layout)
            scene.thread.drive(scene.rollout)
            return scene.rollout.snapshot()

        try:
            return scene.thread.call(install)
        except BaseException:
            if scene.rollout is None or scene.rollout.rollout is not rollout:
                _close_all(built)  # never shown: nothing else will close them
            raise

    def end_rollout(self) -> None:
        """Stop and forget the rollout (before a clip is loaded)."""
        self.scene.thread.call(self._end_rollout)

    def _end_rollout(self) -> None:
        scene = self.scene
        rp, scene.rollout = scene.rollout, None
        scene.thread.drive(*([scene.player] if scene.player else []))
        if rp is None:
            return
        rp.close()
        if scene.view:
            scene.view.end_rollout()
        if scene.player:
            scene.player.show()  # the clip the label and timeline name is drawn again

    def close(self) -> None:
        with contextlib.suppress(Exception):  # a stuck scene thread must not keep the runs going
            self.end_rollout()
        self.scene.thread.close()
        for jobs in self.jobs.values():
            jobs.close()  # a running job is killed; active jobs are recorded as failed (the server stopped)
        self.runs.close()
        self.registry.close()
        if self.scene.viser_server:
            with contextlib.redirect_stdout(io.StringIO()):  # viser prints "Server stopped"
                self.scene.viser_server.stop()


def _build_rollouts(source: RolloutSource, partner: RolloutSource | None, num_envs: int = 1) -> list[Rollout]:
    """A `Rollout` of `source` (`num_envs` envs), and of `partner` when given; those built are closed when
    one fails."""
    sides = [("A", source), ("B", partner)] if partner is not None else [("", source)]
    built: list[Rollout] = []
    try:
        for side, s in sides:
            built.append(_build_side(side, s, num_envs))
    except BaseException:
        _close_all(built)
        raise
    return built


def _build_side(side: str, source: RolloutSource, num_envs: int = 1) -> Rollout:
    """`Rollout(source, num_envs=)`; an A/B side's error (`side` "A" or "B") says which side, still in one line."""
    try:
        return Rollout(source, num_envs=num_envs)
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
