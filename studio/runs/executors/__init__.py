"""What runs a training process for the run manager: `local` (subprocesses of the server) or `ray`
(jobs on a Ray cluster). `make_executor` builds the one a server's settings name."""

from __future__ import annotations

from studio.runs.executors.base import EXECUTORS, Executor, Job, JobState, Launch
from studio.settings import Settings


def make_executor(settings: Settings) -> Executor:
    """The executor of `settings.executor`; Ray is imported only when asked for."""
    if settings.executor == "local":
        from studio.runs.executors.local import LocalExecutor

        return LocalExecutor(settings.stop_timeout_s)
    if settings.executor == "ray":
        from studio.runs.executors.ray import RayExecutor

        return RayExecutor(settings.ray_address, settings.stop_timeout_s)
    raise ValueError(f"unknown executor {settings.executor!r} (known: {', '.join(EXECUTORS)})")


__all__ = ["EXECUTORS", "Executor", "Job", "JobState", "Launch", "make_executor"]
