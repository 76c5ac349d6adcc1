"""The routes every kind of background job has (`studio.jobs.queue`), on the kind's own router: the
list, one job, stopping a job and removing an ended one. A kind adds its start route (its request
fields) and any route of its own result."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from fastapi import APIRouter, HTTPException, Response

from studio.api import StudioDep
from studio.jobs.queue import ACTIVE, Job, JobQueue
from studio.services import Studio


class JobRoutes:
    """`GET ""`, `GET /{job_id}`, `POST /{job_id}/stop` and `DELETE /{job_id}` of the jobs of
    `queue_of(studio)`; `job(studio, id)` finds one for the kind's own routes (404 when there is none)."""

    def __init__(self, router: APIRouter, queue_of: Callable[[Studio], JobQueue], result: str) -> None:
        self.queue_of = queue_of
        kind = router.prefix.strip("/")  # "evals"

        def list_jobs(studio: StudioDep) -> list[dict[str, Any]]:
            return [j.to_json() for j in queue_of(studio).list()]

        def get_job(job_id: int, studio: StudioDep) -> dict[str, Any]:
            return self.job(studio, job_id).to_json()

        def stop_job(job_id: int, studio: StudioDep) -> dict[str, Any]:
            job, queue = self.job(studio, job_id), queue_of(studio)
            if not queue.stop(job_id):
                raise HTTPException(409, f"{queue.kind} {job_id} has already ended ({job.status})")
            return job.to_json()

        def delete_job(job_id: int, studio: StudioDep) -> Response:
            job, queue = self.job(studio, job_id), queue_of(studio)
            if job.status in ACTIVE or not queue.remove(job_id):
                raise HTTPException(409, f"{queue.kind} {job_id} is {job.status}; stop it first")
            return Response(status_code=204)

        router.add_api_route(
            "",
            list_jobs,
            methods=["GET"],
            name=f"list_{kind}",
            description="Every job, newest first: this server's and those a server before it recorded.",
        )
        router.add_api_route(
            "/{job_id}",
            get_job,
            methods=["GET"],
            name=f"get_{kind}",
            description="`status` (queued, running, finished, failed, stopped), `error` (one line; a job the "
            f"server stopped with: `the server stopped while the job ran; ...`) and, when finished, {result}.",
        )
        router.add_api_route(
            "/{job_id}/stop",
            stop_job,
            methods=["POST"],
            name=f"stop_{kind}",
            description="Stop a queued job (it never starts) or a running one (its process group is killed): "
            "status `stopped`. 409 when it had already ended.",
        )
        router.add_api_route(
            "/{job_id}",
            delete_job,
            methods=["DELETE"],
            status_code=204,
            name=f"delete_{kind}",
            description=f"Remove an ended job from the list and delete its folder (`<runs-dir>/{kind}/<id>/`). "
            "409 while it is queued or running: stop it first.",
        )

    def job(self, studio: Studio, job_id: int) -> Job:
        queue = self.queue_of(studio)
        job = queue.get(job_id)
        if job is None:
            raise HTTPException(404, f"no {queue.kind} job {job_id}")
        return job
