"""What the clip player and the rollout player share, so the API drives either through one interface.

A playable belongs to the studio's one scene thread (`studio.scene.thread.SceneThread`): its commands
(`@command` methods) called from any other thread are queued there and waited for, so only that
thread advances, draws and reads the simulation. Between commands the thread asks `due()` when the
playable next wants to advance and calls `tick(now)` then. After every change the scene thread
publishes a `Published` (a version number, the state, and a rollout's newest history rows): `feed()`
reads it from any thread without asking the scene thread, and `snapshot()` off the scene thread returns
its state (no waiting: the event loop may read it). Listeners hear of every drawn frame and state
change, on the scene thread.
"""

from __future__ import annotations

import abc
import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

from studio.scene.thread import SceneThread

F = TypeVar("F", bound=Callable[..., Any])


def command(method: F) -> F:
    """Run `method` on the playable's scene thread (queued and waited for when called from another)."""

    @functools.wraps(method)
    def run(self: Playable, *args: Any, **kwargs: Any) -> Any:
        if self._here():
            return method(self, *args, **kwargs)
        return self.owner.call(method, self, *args, **kwargs)

    return run  # type: ignore[return-value]


@dataclass(frozen=True)
class Published:
    """What the scene thread published after a change; replaced whole, never changed, so any thread may read it."""

    version: int  # counts the changes: a reader that saw this version has nothing new
    state: dict[str, Any]  # the JSON-ready state (`Playable.snapshot`)
    # A rollout's newest history rows, oldest first (`RolloutPlayer.history_rows`' rows, the last
    # `studio.scene.rollout.PUBLISHED_ROWS`); a reader keeps those past the last step it has seen.
    rows: tuple[dict[str, Any], ...] = ()


class Playable(abc.ABC):
    state: Any  # a dataclass with at least `playing`, `speed` and `follow`

    def __init__(self, owner: SceneThread | None) -> None:
        """`owner` None: nothing advances it and its commands run on the caller's thread (a test's)."""
        self.owner = owner
        self._listeners: list[Callable[[Any], None]] = []
        self._feed: Published | None = None

    def add_listener(self, fn: Callable[[Any], None]) -> None:
        """`fn(playable)` after every drawn frame and every state change (on the scene thread)."""
        self._listeners.append(fn)

    # -- commands -------------------------------------------------------------------------------------

    @abc.abstractmethod
    def play(self) -> None: ...

    @command
    def pause(self) -> None:
        self.state.playing = False
        self._changed()

    @command
    def toggle(self) -> None:
        self.pause() if self.state.playing else self.play()

    @abc.abstractmethod
    def step(self, frames: int = 1) -> None:
        """Pause and move `frames` (may be negative)."""

    @abc.abstractmethod
    def seek(self, *, frame: int | None = None, time_s: float | None = None) -> None: ...

    @abc.abstractmethod
    def configure(
        self, *, speed: float | None = None, loop: bool | None = None, follow: bool | None = None
    ) -> None: ...

    def close(self) -> None:  # noqa: B027 - most playables hold nothing
        """Release what the playable holds (a subclass's env); a command."""

    # -- reading --------------------------------------------------------------------------------------

    def snapshot(self) -> dict[str, Any]:
        """The state as the API returns it (JSON-ready): computed now on the scene thread, else the one
        published after the last change."""
        if self._here():
            return self._snapshot()
        return self._feed.state if self._feed is not None else self.owner.call(self._snapshot)

    def _here(self) -> bool:
        return self.owner is None or self.owner.on_thread()

    def published(self) -> dict[str, Any] | None:
        """The state published after the last change (None before the first), from any thread."""
        return self._feed.state if self._feed is not None else None

    def feed(self) -> Published | None:
        """What was published after the last change (None before the first), from any thread."""
        return self._feed

    @abc.abstractmethod
    def _snapshot(self) -> dict[str, Any]: ...

    # -- advancing (the scene thread) -----------------------------------------------------------------

    @abc.abstractmethod
    def due(self) -> float | None:
        """`time.monotonic()` at which `tick` should next run; None: nothing to do until a command."""

    @abc.abstractmethod
    def tick(self, now: float) -> None:
        """Advance what is due at `now` (the scene thread calls it between commands)."""

    def _published_rows(self) -> tuple[dict[str, Any], ...]:
        """The history rows to publish with the state (a rollout's; a clip has none)."""
        return ()

    def _changed(self) -> None:
        version = self._feed.version + 1 if self._feed is not None else 1
        self._feed = Published(version, self._snapshot(), self._published_rows())
        for fn in self._listeners:
            try:
                fn(self)
            except Exception as e:  # noqa: BLE001 - a listener's hiccup must not stop the playback
                print(f"{type(self).__name__} listener: {e!r}")
