"""The kinds of background job a studio runs, each a `JobQueue` subclass. A new kind is its module in
`studio/jobs/`, its routes in `studio/api/` and one line here: the studio makes its queue
(`studio.app.create_studio`), and the stream pushes its job list under its `folder_name`
(`studio.api.stream`)."""

from __future__ import annotations

from studio.jobs.evals import EvalJobs
from studio.jobs.queue import JobQueue
from studio.jobs.videos import VideoJobs

JOB_KINDS: tuple[type[JobQueue], ...] = (EvalJobs, VideoJobs)
