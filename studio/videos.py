"""MP4 export jobs: `mimickit video` of a clip (on its character) or of a policy checkpoint, as a
background subprocess per job.

A job runs in its own folder, `<runs-dir>/videos/<id>/` (its working directory: MuJoCo's log and the
like land there), in its own session (process group), so that `stop`, stopping the server or the time
limit kills the renderer and anything it started. For a checkpoint, the arg file `mimickit video` needs
is written there, naming the env, agent and engine configs. The video is `video.mp4` in that folder,
the command's output `console.log`. One worker thread renders the jobs one after another (rendering
takes the cores a training needs), so no request waits on it. A job that fails says why in one line.

The queue, the worker and the job records are `studio/job_queue.py`'s: each job's `job.json` lets a
restarted server list the jobs of the one before (a finished one's MP4 is still served).
"""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from studio.job_process import failure_line
from studio.job_queue import ACTIVE, Job, JobQueue
from studio.settings import Settings

__all__ = ["ACTIVE", "VIDEOS_DIR", "VIDEO_FILE", "VideoJob", "VideoJobs"]

VIDEOS_DIR = "videos"
VIDEO_FILE = "video.mp4"
VIDEO_COMMAND = [sys.executable, "-m", "mimickit.cli", "video"]
TIME_LIMIT_S = 600.0  # a render that takes longer than this is killed


@dataclass(kw_only=True)
class VideoJob(Job):
    PATH_FIELDS = ("folder", "clip", "char", "checkpoint", "data_dir")

    seconds: float
    width: int
    height: int
    clip: Path | None = None
    char: Path | None = None
    checkpoint: Path | None = None
    configs: dict[str, Path] = field(default_factory=dict)
    run_id: int | None = None
    data_dir: Path | None = None
    bytes: int | None = None

    @property
    def file(self) -> Path:
        return self.folder / VIDEO_FILE

    @classmethod
    def from_record(cls, data: dict[str, Any]) -> VideoJob:
        job = super().from_record(data)
        job.configs = {str(k): Path(v) for k, v in dict(job.configs).items()}
        return job  # type: ignore[return-value]

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


class VideoJobs(JobQueue[VideoJob]):
    """The video jobs under `<runs-dir>/videos/` and the worker thread that renders them."""

    job_type = VideoJob
    cannot_run = "could not render the video"

    def __init__(
        self, settings: Settings, command: list[str] | None = None, time_limit_s: float = TIME_LIMIT_S
    ) -> None:
        self.settings = settings
        self.command = list(command or VIDEO_COMMAND)
        self.time_limit_s = time_limit_s
        super().__init__(settings.runs_dir / VIDEOS_DIR, "videos")

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
        (env_config, agent_config and optionally engine_config and motion_file)."""
        return self._submit(
            seconds, width, height, checkpoint=checkpoint, configs=configs, run_id=run_id, data_dir=data_dir
        )

    def _submit(self, seconds: float, width: int, height: int, **source: Any) -> VideoJob:
        def make(job_id: int, folder: Path) -> VideoJob:
            job = VideoJob(id=job_id, folder=folder, seconds=seconds, width=width, height=height, **source)
            job.command = self._argv(job)
            return job

        return self._add(make)

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

    def _run(self, job: VideoJob) -> None:
        console = job.folder / "console.log"
        with open(console, "wb") as out:
            proc = self._launch(job, out, subprocess.STDOUT)
            if proc is None:
                return
            code = self._wait(proc, self.time_limit_s)
        if job.status != "running":  # stopped meanwhile
            return
        if code is None:
            self._end(job, "failed", f"mimickit video took longer than {self.time_limit_s:g} s and was stopped")
        elif code != 0:
            self._end(job, "failed", failure_line("mimickit video", console, code))
        elif not job.file.is_file():
            self._end(job, "failed", f"mimickit video exited without writing {VIDEO_FILE}")
        else:
            self._end(job, "finished", bytes=job.file.stat().st_size)
