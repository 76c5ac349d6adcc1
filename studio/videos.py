"""MP4 export jobs: `mimickit video` of a clip (on its character) or of a policy checkpoint, as a
background subprocess per job.

A job runs in its own folder, `<runs-dir>/videos/<id>/` (its working directory: MuJoCo's log and the
like land there), in its own session (process group), so that stopping the server or the time limit
kills the renderer and anything it started. For a checkpoint, the arg file `mimickit video` needs is
written there, naming the env, agent and engine configs. The video is `video.mp4` in that folder, the
command's output `console.log`. One worker thread renders the jobs one after another (rendering takes
the cores a training needs), so no request waits on it. A job that fails says why in one line.

Jobs live in memory (a restarted server starts with none); their folders stay.
"""

from __future__ import annotations

import atexit
import os
import queue
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from studio.job_process import failure_line, kill_group
from studio.library import one_line
from studio.runs import child_env
from studio.settings import Settings

VIDEOS_DIR = "videos"
VIDEO_FILE = "video.mp4"
VIDEO_COMMAND = [sys.executable, "-m", "mimickit.cli", "video"]
TIME_LIMIT_S = 600.0  # a render that takes longer than this is killed
ACTIVE = ("queued", "running")


@dataclass
class VideoJob:
    id: int
    folder: Path
    seconds: float
    width: int
    height: int
    clip: Path | None = None
    char: Path | None = None
    checkpoint: Path | None = None
    configs: dict[str, Path] = field(default_factory=dict)
    run_id: int | None = None
    data_dir: Path | None = None
    status: str = "queued"  # queued, running, then finished or failed
    error: str | None = None
    command: list[str] = field(default_factory=list)
    bytes: int | None = None
    created_at: float = field(default_factory=time.time)
    started_at: float | None = None
    ended_at: float | None = None

    @property
    def file(self) -> Path:
        return self.folder / VIDEO_FILE

    def to_json(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "status": self.status,
            "error": self.error,
            "kind": "clip" if self.clip is not None else "policy",
            "clip": str(self.clip) if self.clip else None,
            "char": str(self.char) if self.char else None,
            "checkpoint": str(self.checkpoint) if self.checkpoint else None,
            "run_id": self.run_id,
            "seconds": self.seconds,
            "width": self.width,
            "height": self.height,
            "folder": str(self.folder),
            "command": self.command,
            "bytes": self.bytes,
            "download": f"/api/videos/{self.id}/file" if self.status == "finished" else None,
            "created_at": self.created_at,
            "started_at": self.started_at,
            "ended_at": self.ended_at,
        }


class VideoJobs:
    """The video jobs of one server and the worker thread that renders them."""

    def __init__(
        self, settings: Settings, command: list[str] | None = None, time_limit_s: float = TIME_LIMIT_S
    ) -> None:
        self.settings = settings
        self.command = list(command or VIDEO_COMMAND)
        self.time_limit_s = time_limit_s
        self._jobs: dict[int, VideoJob] = {}
        self._lock = threading.Lock()
        self._queue: queue.Queue[VideoJob | None] = queue.Queue()
        self._proc: subprocess.Popen[bytes] | None = None  # the running job's, set and read under the lock
        self._next_id = 1
        self._closed = False
        self._thread = threading.Thread(target=self._work, name="videos", daemon=True)
        self._thread.start()
        atexit.register(self.close)  # a server that exits leaves no renderer running

    def submit_clip(self, clip: Path, char: Path, *, seconds: float, width: int, height: int) -> VideoJob:
        """Queue `mimickit video --motion clip --char char`."""
        return self._submit(seconds, width, height, clip=clip, char=char)

    def submit_policy(
        self,
        checkpoint: Path,
        configs: dict[str, Path],
        *,
        seconds: float,
        width: int,
        height: int,
        run_id: int | None = None,
        data_dir: Path | None = None,
    ) -> VideoJob:
        """Queue `mimickit video --model_file checkpoint` with an arg file naming `configs`
        (env_config, agent_config and optionally engine_config)."""
        return self._submit(
            seconds, width, height, checkpoint=checkpoint, configs=configs, run_id=run_id, data_dir=data_dir
        )

    def get(self, job_id: int) -> VideoJob | None:
        with self._lock:
            return self._jobs.get(job_id)

    def list(self) -> list[VideoJob]:
        with self._lock:
            return sorted(self._jobs.values(), key=lambda j: -j.id)

    def close(self) -> None:
        """Stop the worker; a running render's process group is killed."""
        self._closed = True
        with self._lock:
            proc = self._proc
        if proc is not None:
            kill_group(proc)
        self._queue.put(None)
        self._thread.join(timeout=5)

    def _submit(self, seconds: float, width: int, height: int, **source: Any) -> VideoJob:
        with self._lock:
            job_id, self._next_id = self._next_id, self._next_id + 1
            folder = self.settings.runs_dir / VIDEOS_DIR / f"{job_id:04d}-{int(time.time())}"
            folder.mkdir(parents=True, exist_ok=True)
            job = VideoJob(job_id, folder, seconds, width, height, **source)
            job.command = self._argv(job)
            self._jobs[job_id] = job
        self._queue.put(job)
        return job

    def _argv(self, job: VideoJob) -> list[str]:
        argv = [*self.command, "--out", str(job.file), "--seconds", f"{job.seconds:g}"]
        argv += ["--width", str(job.width), "--height", str(job.height)]
        if job.clip is not None:
            argv += ["--motion", str(job.clip), "--char", str(job.char)]
        else:
            arg_file = job.folder / "args.txt"
            arg_file.write_text("".join(f"--{k} {v}\n" for k, v in job.configs.items()))
            argv += ["--model_file", str(job.checkpoint), "--arg_file", str(arg_file)]
        data_dir = job.data_dir or self.settings.data_dir
        if data_dir is not None:
            argv += ["--data_dir", str(data_dir)]
        return argv

    # -- the worker thread -------------------------------------------------------------------------

    def _work(self) -> None:
        while True:
            job = self._queue.get()
            if job is None or self._closed:
                return
            try:
                self._run(job)
            except Exception as e:  # noqa: BLE001 - a job that cannot run is a failed job, not a dead worker
                self._end(job, "failed", one_line(f"could not render the video: {type(e).__name__}: {e}"))

    def _run(self, job: VideoJob) -> None:
        console = job.folder / "console.log"
        with open(console, "wb") as out:
            with self._lock:
                job.status, job.started_at = "running", time.time()
                self._proc = proc = subprocess.Popen(
                    job.command,
                    stdin=subprocess.DEVNULL,
                    stdout=out,
                    stderr=subprocess.STDOUT,
                    cwd=job.folder,
                    env={**os.environ, **child_env()},
                    start_new_session=True,  # its own process group: the time limit and `close` reach its children
                )
            try:
                code = proc.wait(timeout=self.time_limit_s)
            except subprocess.TimeoutExpired:
                kill_group(proc)
                proc.wait()
                code = None
        with self._lock:
            self._proc = None
        if code is None:
            self._end(job, "failed", f"mimickit video took longer than {self.time_limit_s:g} s and was stopped")
        elif code != 0:
            self._end(job, "failed", failure_line("mimickit video", console, code))
        elif not job.file.is_file():
            self._end(job, "failed", f"mimickit video exited without writing {VIDEO_FILE}")
        else:
            job.bytes = job.file.stat().st_size
            self._end(job, "finished")

    def _end(self, job: VideoJob, status: str, error: str | None = None) -> None:
        with self._lock:
            job.status, job.error, job.ended_at = status, error, time.time()
