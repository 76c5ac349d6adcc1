"""What the clip player and the rollout player share, so the API drives either through one interface.

A playable owns one worker thread that advances and draws while playing. Commands come from any thread
(request handlers, the viser key handler) and take the playable's lock; `_wake` cuts the worker's idle
wait short. Listeners (the live state the page is streamed) hear of every drawn frame and state change.
"""

from __future__ import annotations

import abc
import threading
from collections.abc import Callable
from typing import Any


class Playable(abc.ABC):
    state: Any  # a dataclass with at least `playing`, `speed` and `follow`

    def __init__(self, thread_name: str) -> None:
        self._lock = threading.RLock()
        self._wake = threading.Event()
        self._closed = threading.Event()
        self._listeners: list[Callable[[Any], None]] = []
        self._thread = threading.Thread(target=self._run, name=thread_name, daemon=True)

    def add_listener(self, fn: Callable[[Any], None]) -> None:
        """`fn(playable)` after every drawn frame and every state change."""
        self._listeners.append(fn)

    # -- commands (any thread) ----------------------------------------------------------------------

    @abc.abstractmethod
    def play(self) -> None: ...

    def pause(self) -> None:
        with self._lock:
            self.state.playing = False
        self._changed()

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

    @abc.abstractmethod
    def snapshot(self) -> dict[str, Any]:
        """The state as the API returns it (JSON-ready)."""

    def close(self) -> None:
        self._closed.set()
        self._wake.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5)

    # -- the worker ----------------------------------------------------------------------------------

    def _start(self) -> None:
        """Start the worker; a subclass calls it once its state is ready to draw."""
        self._thread.start()

    @abc.abstractmethod
    def _run(self) -> None:
        """The worker's loop, until `_closed` is set."""

    def _changed(self) -> None:
        for fn in self._listeners:
            try:
                fn(self)
            except Exception as e:  # noqa: BLE001 - a listener's hiccup must not stop the playback
                print(f"{self._thread.name} listener: {e!r}")
