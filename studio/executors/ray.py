"""Runs as Ray jobs (`mimickit-studio serve --executor ray --ray-address http://HOST:8265`).

Each run's process is one job submitted through Ray's Job Submission API, with the CPUs and GPUs it
asks for as the entrypoint's resources: Ray queues the jobs (PENDING) until a node has them free, so
queueing and concurrency are the cluster's, not the studio's. The entrypoint changes into the run
folder and execs the trainer there, so the trainer's files (and MuJoCo's MUJOCO_LOG.TXT) land in the
run folder on whatever node runs it: the studio's `--runs-dir` must be a path every node sees (a shared
filesystem), see docs/studio.md. Ray stops a job with SIGTERM and SIGKILLs it after
`RAY_JOB_STOP_WAIT_TIME_S` (3 s by default: too short for a checkpoint); every job is submitted with
that set, through its runtime_env, to the studio's stop timeout. Jobs belong to the cluster, not the
server: a restarted studio asks Ray about the job ids in its registry and re-attaches.
"""

from __future__ import annotations

import shlex
import time

from mimickit.util.errors import MimicKitError
from studio.executors.base import Job, JobState, Launch

STOP_WAIT_ENV = "RAY_JOB_STOP_WAIT_TIME_S"  # read by Ray's job supervisor (ray/dashboard/modules/job)


class RayExecutor:
    name = "ray"
    queues = True  # every run is submitted at once; Ray starts each when its resources are free

    def __init__(self, address: str, stop_timeout_s: float) -> None:
        try:
            from ray.job_submission import JobSubmissionClient
        except ImportError:
            raise MimicKitError("--executor ray needs Ray: pip install -e '.[ray]'") from None
        self.address = address
        self.stop_timeout_s = stop_timeout_s
        try:
            self.client = JobSubmissionClient(address)  # asks the dashboard for its version
        except Exception as e:  # ConnectionError, a refused or odd reply: one line, not Ray's traceback
            first = (str(e).strip().splitlines() or [type(e).__name__])[0][:200]
            raise MimicKitError(f"--ray-address {address}: no Ray dashboard answers there ({first})") from None
        self._running_since: dict[str, float] = {}  # job id -> when this server first saw it RUNNING

    def submit(self, launch: Launch) -> str:
        env = " ".join(f"{k}={shlex.quote(v)}" for k, v in launch.env.items())
        entrypoint = f"cd {shlex.quote(str(launch.work_dir))} && exec env {env} {shlex.join(launch.argv)}"
        return self.client.submit_job(
            entrypoint=entrypoint,
            entrypoint_num_cpus=launch.num_cpus,
            entrypoint_num_gpus=launch.num_gpus,
            runtime_env={"env_vars": {STOP_WAIT_ENV: str(max(1, round(self.stop_timeout_s)))}},
            metadata={"studio_run": launch.name},
        )

    def status(self, job_id: str, argv_hint: str = "") -> Job | None:
        try:
            info = self.client.get_job_info(job_id)
        except RuntimeError as e:
            if "404" in str(e):  # the cluster does not know it (e.g. it was restarted since)
                return None
            raise
        state = info.status.value if hasattr(info.status, "value") else str(info.status)
        if state == "PENDING":
            return Job(JobState.PENDING, message=info.message)
        if state == "RUNNING":
            since = self._running_since.setdefault(job_id, time.time())
            return Job(JobState.RUNNING, started_at=since, message=info.message)
        # SUCCEEDED, FAILED, STOPPED: ended. Ray's start_time is the submission's; the start is when
        # this server saw it running (within a poll), or the submission for a job that never ran.
        started = self._running_since.pop(job_id, None) or (info.start_time or 0) / 1000 or None
        ended = (info.end_time or 0) / 1000 or time.time()
        return Job(JobState.ENDED, started, ended, info.driver_exit_code, info.message)

    def stop(self, job_id: str) -> None:
        self.client.stop_job(job_id)

    def logs(self, job_id: str) -> str | None:
        return self.client.get_job_logs(job_id)

    def close(self) -> None:
        pass
