"""Evaluation jobs: `mimickit eval --json` on a checkpoint, as a background subprocess per job.

A job runs in its own folder, `<runs-dir>/evals/<id>/` (its working directory: MuJoCo's log and the
like land there, not in the server's), with the arg file it was given or, for a run's checkpoint, one
written there naming the configs the trainer copied beside the checkpoint. The command's stdout (the
JSON report) and stderr go to files in that folder; one worker thread runs the jobs one after another
(an eval takes the cores a training needs) and parses the report, so no request waits on it. A job
that fails says why in one line: `mimickit`'s own `error:` line, else the last line it printed.
`stop` ends a queued job before it starts and kills a running one's process group; `remove` forgets an
ended job and deletes its folder.

Jobs live in memory (a restarted server starts with none); their folders stay.
"""

from __future__ import annotations

import atexit
import json
import os
import queue
import shutil
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from mimickit.util.errors import MimicKitError
from studio.job_process import failure_line, kill_group
from studio.library import one_line
from studio.runs import child_env
from studio.settings import Settings

EVALS_DIR = "evals"
EVAL_COMMAND = [sys.executable, "-m", "mimickit.cli", "eval"]
ACTIVE = ("queued", "running")


@dataclass
class EvalJob:
    id: int
    checkpoint: Path
    arg_file: Path
    motion_file: str | None
    episodes: int
    folder: Path
    run_id: int | None = None
    status: str = "queued"  # queued, running, then finished, failed or stopped
    error: str | None = None
    rows: list[dict[str, Any]] = field(default_factory=list)
    mean: dict[str, Any] | None = None
    command: list[str] = field(default_factory=list)
    created_at: float = field(default_factory=time.time)
    started_at: float | None = None
    ended_at: float | None = None

    def to_json(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "status": self.status,
            "error": self.error,
            "checkpoint": str(self.checkpoint),
            "arg_file": str(self.arg_file),
            "motion_file": self.motion_file,
            "episodes": self.episodes,
            "run_id": self.run_id,
            "folder": str(self.folder),
            "command": self.command,
            "rows": self.rows,
            "mean": self.mean,
            "created_at": self.created_at,
            "started_at": self.started_at,
            "ended_at": self.ended_at,
        }


class EvalJobs:
    """The jobs of one server and the worker thread that runs them."""

    def __init__(self, settings: Settings, command: list[str] | None = None) -> None:
        self.settings = settings
        self.command = list(command or EVAL_COMMAND)
        self._jobs: dict[int, EvalJob] = {}
        self._lock = threading.Lock()
        self._queue: queue.Queue[EvalJob | None] = queue.Queue()
        self._proc: subprocess.Popen[bytes] | None = None  # the running job's, set and read under the lock
        self._next_id = 1  # never reused: a removed job's id does not come back as another job
        self._closed = False
        self._thread = threading.Thread(target=self._work, name="evals", daemon=True)
        self._thread.start()
        atexit.register(self.close)  # a server that exits leaves no eval running

    def submit(
        self,
        checkpoint: Path,
        *,
        arg_file: Path | None = None,
        configs: dict[str, Path] | None = None,
        motion_file: str | None = None,
        episodes: int = 8,
        run_id: int | None = None,
    ) -> EvalJob:
        """Queue `mimickit eval` of `checkpoint` with `arg_file`, or with an arg file written from
        `configs` (env_config, agent_config, engine_config: the files beside a run's checkpoint)."""
        if arg_file is None and not configs:
            raise MimicKitError("an eval needs an arg file or the configs beside the checkpoint")
        with self._lock:
            job_id, self._next_id = self._next_id, self._next_id + 1
            folder = self.settings.runs_dir / EVALS_DIR / f"{job_id:04d}-{int(time.time())}"
            folder.mkdir(parents=True, exist_ok=True)
            if arg_file is None:
                arg_file = folder / "args.txt"
                arg_file.write_text("".join(f"--{k} {v}\n" for k, v in configs.items() if v is not None))
            job = EvalJob(job_id, checkpoint, arg_file, motion_file, episodes, folder, run_id)
            job.command = self._argv(job)
            self._jobs[job_id] = job
        self._queue.put(job)
        return job

    def get(self, job_id: int) -> EvalJob | None:
        with self._lock:
            return self._jobs.get(job_id)

    def list(self) -> list[EvalJob]:
        with self._lock:
            return sorted(self._jobs.values(), key=lambda j: -j.id)

    def stop(self, job_id: int) -> bool:
        """Stop a queued job (it will not start) or a running one (its process group killed): status
        `stopped`. False when the job had already ended."""
        with self._lock:
            job = self._jobs.get(job_id)
            if job is None or job.status not in ACTIVE:
                return False
            running, proc = job.status == "running", self._proc
            job.status, job.error, job.ended_at = "stopped", None, time.time()
        if running and proc is not None:
            kill_group(proc)
        return True

    def remove(self, job_id: int) -> bool:
        """Forget an ended job and delete its folder. False while it is queued or running."""
        with self._lock:
            job = self._jobs.get(job_id)
            if job is None or job.status in ACTIVE:
                return False
            del self._jobs[job_id]
        shutil.rmtree(job.folder, ignore_errors=True)  # a folder this server made under <runs-dir>/evals
        return True

    def close(self) -> None:
        """Stop the worker; a running eval's process group is killed."""
        self._closed = True
        proc = self._proc
        if proc is not None:
            kill_group(proc)
        self._queue.put(None)
        self._thread.join(timeout=5)

    def _argv(self, job: EvalJob) -> list[str]:
        argv = [*self.command, "--arg_file", str(job.arg_file), "--model_file", str(job.checkpoint)]
        argv += ["--episodes", str(job.episodes), "--json"]
        if job.motion_file:
            argv += ["--motion_file", job.motion_file]
        if self.settings.data_dir is not None:
            argv += ["--data_dir", str(self.settings.data_dir)]
        return argv

    # -- the worker thread -------------------------------------------------------------------------

    def _work(self) -> None:
        while True:
            job = self._queue.get()
            if job is None or self._closed:
                return
            if job.status != "queued":  # stopped while it waited
                continue
            try:
                self._run(job)
            except Exception as e:  # noqa: BLE001 - a job that cannot run is a failed job, not a dead worker
                self._end(job, "failed", error=one_line(f"could not run the eval: {type(e).__name__}: {e}"))

    def _run(self, job: EvalJob) -> None:
        out_path, err_path = job.folder / "report.json", job.folder / "console.log"
        env = {**os.environ, **child_env()}
        with open(out_path, "wb") as out, open(err_path, "wb") as err:
            with self._lock:  # a `stop` either comes first (the job never starts) or sees the process
                if job.status != "queued":
                    return
                job.status, job.started_at = "running", time.time()
                self._proc = proc = subprocess.Popen(
                    job.command,
                    stdin=subprocess.DEVNULL,
                    stdout=out,
                    stderr=err,
                    cwd=job.folder,
                    env=env,
                    start_new_session=True,  # its own process group: `stop` and `close` reach its children too
                )
            code = proc.wait()
        with self._lock:
            self._proc = None
            if job.status == "stopped":
                return
        if code != 0:
            self._end(job, "failed", error=failure_line("mimickit eval", err_path, code))
            return
        try:
            report = json.loads(out_path.read_text())
            rows, mean = list(report["rows"]), report["mean"]
        except (ValueError, KeyError, TypeError) as e:
            self._end(job, "failed", error=one_line(f"mimickit eval printed no report ({type(e).__name__}: {e})"))
            return
        self._end(job, "finished", rows=rows, mean=mean)

    def _end(self, job: EvalJob, status: str, error: str | None = None, **report: Any) -> None:
        """The job's end, with its `rows` and `mean` when it finished; a job stopped meanwhile stays stopped."""
        with self._lock:
            if job.status == "stopped":
                return
            job.status, job.error, job.ended_at = status, error, time.time()
            job.rows, job.mean = report.get("rows", job.rows), report.get("mean", job.mean)


def clip_env_config(env_config: Path, clip: Path, out: Path) -> Path:
    """A copy of `env_config` whose `motion_file` is `clip` (to roll out one row of an eval)."""
    from mimickit.util.config import load_yaml_text, read_text_file

    data = load_yaml_text(read_text_file(env_config, "env config"), env_config) or {}
    section = data.get("env") if isinstance(data.get("env"), dict) else data
    if "motion_file" not in section:
        raise MimicKitError(f"{env_config}: the env config has no motion_file to replace")
    section["motion_file"] = str(clip)
    out.write_text(yaml.safe_dump(data, sort_keys=False))
    return out
