"""The one thread that owns the 3D scene (mjlab's viewer style): the clip player, the rollout and the
viser scene are touched only here. Commands come from any thread (REST handlers, viser's key handler,
the stream's readers) as callables put on a queue; the caller waits for the result through a
`concurrent.futures.Future`, so an error raised by the command is raised again in the caller. Between
commands the thread advances what it drives (`Playable.due` / `Playable.tick`): a clip at fps × speed,
a rollout at its control rate × speed. Commands run one at a time in the order they were queued.
"""

from __future__ import annotations

import concurrent.futures
import logging
import queue
import threading
import time
from collections.abc import Callable
from typing import Any, Protocol, TypeVar

LOG = logging.getLogger("studio")
T = TypeVar("T")
COMMAND_TIMEOUT_S = 30.0  # a command waits at most this long (showing a rollout builds its meshes: ~1 s)
IDLE_WAIT_S = 1.0  # nothing due: the thread sleeps on the queue this long at most (nothing is computed)
_STOP = object()


class Driven(Protocol):
    """What the thread advances between commands: a `studio.scene.playable.Playable` (declared here so
    that this lower module does not import the playables built on it)."""

    def due(self) -> float | None: ...

    def tick(self, now: float) -> None: ...

    def pause(self) -> None: ...


class SceneTimeout(RuntimeError):
    """A command was not done within its timeout (the scene thread is busy or stuck)."""


class SceneThread:
    """Runs commands and advances the driven playables, on one thread (see the module docstring)."""

    def __init__(self, name: str = "scene") -> None:
        self._queue: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._driven: list[Driven] = []
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._stopped = threading.Event()
        self._thread.start()

    def on_thread(self) -> bool:
        """Whether the caller is the scene thread itself (a command calling another runs it at once)."""
        return threading.current_thread() is self._thread

    def submit(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> concurrent.futures.Future[T]:
        """Queue `fn(*args, **kwargs)`; its Future. After `close`, the Future fails at once."""
        fut: concurrent.futures.Future[T] = concurrent.futures.Future()
        if self._stopped.is_set():
            fut.set_exception(RuntimeError("the scene thread has stopped"))
            return fut
        self._queue.put((fn, args, kwargs, fut))
        return fut

    def call(self, fn: Callable[..., T], *args: Any, timeout: float = COMMAND_TIMEOUT_S, **kwargs: Any) -> T:
        """Run `fn` on the scene thread and return its result (its exception raised here)."""
        if self.on_thread():
            return fn(*args, **kwargs)
        fut = self.submit(fn, *args, **kwargs)
        try:
            return fut.result(timeout)
        except concurrent.futures.TimeoutError:
            fut.cancel()  # not run at all if it has not started yet
            raise SceneTimeout(f"the 3D scene did not answer within {timeout:g} s (busy); try again") from None

    def drive(self, *playables: Driven) -> None:
        """Advance these between commands (and nothing else); scene thread only (a command)."""
        self._check_thread()
        self._driven = list(playables)

    @property
    def driven(self) -> list[Driven]:
        return list(self._driven)

    def close(self, timeout: float = 5.0) -> None:
        """Stop after the commands already queued; later ones fail."""
        if self._stopped.is_set():
            return
        self._queue.put(_STOP)
        if not self.on_thread():
            self._thread.join(timeout)

    def _check_thread(self) -> None:
        if not self.on_thread():
            raise RuntimeError("a scene command called off the scene thread (use SceneThread.call)")

    def _run(self) -> None:
        while True:
            due = min((d for p in self._driven if (d := p.due()) is not None), default=None)
            wait = IDLE_WAIT_S if due is None else min(IDLE_WAIT_S, max(0.0, due - time.monotonic()))
            try:
                item = self._queue.get(timeout=wait) if wait > 0 else self._queue.get_nowait()
            except queue.Empty:
                item = None
            if item is _STOP:
                break
            if item is not None:
                self._run_command(*item)
            now = time.monotonic()
            for p in self._driven:  # a command may have changed what is driven: read it again
                d = p.due()
                if d is not None and d <= now:
                    self._tick(p, now)
        self._stopped.set()
        self._fail_pending()

    @staticmethod
    def _run_command(fn: Callable[..., Any], args: tuple, kwargs: dict, fut: concurrent.futures.Future) -> None:
        if not fut.set_running_or_notify_cancel():
            return  # its caller gave up waiting before it started
        try:
            fut.set_result(fn(*args, **kwargs))
        except BaseException as e:  # noqa: BLE001 - raised again in the caller
            fut.set_exception(e)

    @staticmethod
    def _tick(p: Driven, now: float) -> None:
        try:
            p.tick(now)
        except Exception as e:  # noqa: BLE001 - a failing playable pauses; the thread serves the others
            LOG.warning("scene: advancing %s failed; paused", type(p).__name__, exc_info=e)
            try:
                p.pause()
            except Exception:  # noqa: BLE001
                LOG.exception("scene: pausing %s failed", type(p).__name__)

    def _fail_pending(self) -> None:
        while True:
            try:
                item = self._queue.get_nowait()
            except queue.Empty:
                return
            if item is not _STOP and item[3].set_running_or_notify_cancel():
                item[3].set_exception(RuntimeError("the scene thread has stopped"))
