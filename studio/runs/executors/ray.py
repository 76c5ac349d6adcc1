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

The address is the dashboard's (`http(s)://HOST:PORT`, or `HOST:PORT` for `http://HOST:PORT`). Ray's
client waits without a timeout for the dashboard's first answer, so the studio first probes it with
one: an address that accepts connections and never answers is refused in one line, not a silent hang;
every later request of the client has a timeout too (`timed_client`).
"""

from __future__ import annotations

import http.client
import importlib.util
import shlex
import time
import urllib.error
import urllib.request
from typing import Any
from urllib.parse import urlsplit

from mimickit.util.errors import MimicKitError
from studio.runs.executors.base import Job, JobState, Launch
from studio.security import shown_path

STOP_WAIT_ENV = "RAY_JOB_STOP_WAIT_TIME_S"  # read by Ray's job supervisor (ray/dashboard/modules/job)
MAX_ADDRESS_CHARS = 2048  # a URL's usual limit; a host name alone is at most 253
PROBE_TIMEOUT_S = 10.0  # to connect, then to each read of the dashboard's first answer
REQUEST_TIMEOUT_S = 30.0  # each later request of Ray's client (submit, status, stop, logs)


def dashboard_url(address: str) -> str:
    """The dashboard URL `address` names (`HOST:PORT` -> `http://HOST:PORT`); MimicKitError in one
    line for an address too long, of another scheme or without a host."""
    shown = shown_path(address)
    if len(address) > MAX_ADDRESS_CHARS:
        raise MimicKitError(f"--ray-address {shown}: too long for an address (at most {MAX_ADDRESS_CHARS:,} chars)")
    url = address.strip().rstrip("/")
    url = url if "://" in url else f"http://{url}"
    try:
        parts = urlsplit(url)
        _ = parts.port  # a port that is not a number raises here
    except ValueError as e:
        raise MimicKitError(f"--ray-address {shown}: not an address ({e})") from None
    if parts.scheme not in ("http", "https") or not parts.hostname or any(c.isspace() for c in url):
        raise MimicKitError(
            f"--ray-address {shown}: give the Ray dashboard's address, http://HOST:PORT (e.g. http://127.0.0.1:8265)"
        )
    return url


def probe_dashboard(url: str, timeout_s: float = PROBE_TIMEOUT_S) -> None:
    """Ask `url` for `/api/version` with a timeout: any HTTP answer will do (Ray's client then checks
    the version and its own authentication); MimicKitError in one line when none comes."""
    try:
        with urllib.request.urlopen(f"{url}/api/version", timeout=timeout_s) as response:
            response.read(1)
    except urllib.error.HTTPError:
        return  # it answers: Ray's client says what is wrong with the answer
    except (OSError, http.client.HTTPException) as e:  # refused, timed out, not HTTP, a TLS failure
        reason = getattr(e, "reason", None) or e
        detail = (str(reason).strip().splitlines() or [""])[0][:200] or type(reason).__name__
        if isinstance(reason, TimeoutError):
            detail = f"it accepts connections but sent no answer within {timeout_s:g} s"
        raise MimicKitError(f"--ray-address {shown_path(url)}: no Ray dashboard answers there ({detail})") from None


def timed_client(address: str, timeout_s: float) -> Any:
    """Ray's `JobSubmissionClient` with a timeout on every request (Ray's own have none): a dashboard
    that stops answering later is an error the run manager reports, not its thread stuck for good."""
    from ray.job_submission import JobSubmissionClient

    class TimedClient(JobSubmissionClient):
        def _do_request(self, method: str, endpoint: str, **kwargs: Any) -> Any:
            kwargs.setdefault("timeout", timeout_s)  # passed on to requests.request
            return super()._do_request(method, endpoint, **kwargs)

    return TimedClient(address)


class RayExecutor:
    name = "ray"
    queues = True  # every run is submitted at once; Ray starts each when its resources are free

    def __init__(self, address: str, stop_timeout_s: float, request_timeout_s: float = REQUEST_TIMEOUT_S) -> None:
        if importlib.util.find_spec("ray") is None:
            raise MimicKitError("--executor ray needs Ray: pip install -e '.[ray]'")
        self.address = dashboard_url(address)
        self.stop_timeout_s = stop_timeout_s
        probe_dashboard(self.address)
        try:
            self.client = timed_client(self.address, request_timeout_s)  # asks the dashboard for its version
        except Exception as e:  # ConnectionError, a refused or odd reply: one line, not Ray's traceback
            first = (str(e).strip().splitlines() or [type(e).__name__])[0][:200]
            raise MimicKitError(
                f"--ray-address {shown_path(address)}: no Ray dashboard answers there ({first})"
            ) from None
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
