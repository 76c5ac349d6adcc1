"""MP4 export jobs: `mimickit video` of a clip (on its character) or of a policy checkpoint, as a
background subprocess per job on the shared job queue (`studio/jobs/queue.py`: its folder
`<runs-dir>/videos/<id>/`, one worker thread, records a restarted server lists, `stop` and `remove`).

For a checkpoint, the arg file `mimickit video` needs is written into the job's folder, naming the env,
agent and engine configs. The video is `video.mp4` in that folder (a finished job's MP4 is still served
after a restart); its size is the job's result.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from studio.jobs.queue import ACTIVE, Job, JobFailed, JobQueue, write_arg_file
from studio.settings import Settings

__all__ = ["ACTIVE", "VIDEOS_DIR", "VIDEO_FILE", "VideoJob", "VideoJobs"]

VIDEOS_DIR = "videos"
VIDEO_FILE = "video.mp4"
VIDEO_COMMAND = [sys.executable, "-m", "mimickit.cli", "video"]


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
            **super().to_json(),
            "kind": "clip" if self.clip is not None else "policy",
            "clip": str(self.clip) if self.clip else None,
            "char": str(self.char) if self.char else None,
            "checkpoint": str(self.checkpoint) if self.checkpoint else None,
            "run_id": self.run_id,
            "seconds": self.seconds,
            "width": self.width,
            "height": self.height,
            "bytes": self.bytes,
            "download": f"/api/videos/{self.id}/file" if self.status == "finished" else None,
        }


class VideoJobs(JobQueue[VideoJob]):
    """The video jobs under `<runs-dir>/videos/` and the worker thread that renders them."""

    job_type = VideoJob
    kind = "video"
    cannot_run = "could not render the video"
    folder_name = VIDEOS_DIR
    program = "mimickit video"
    default_command = VIDEO_COMMAND

    def _time_limit(self, settings: Settings) -> float:
        return settings.video_time_limit_s

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
            return VideoJob(id=job_id, folder=folder, seconds=seconds, width=width, height=height, **source)

        return self._add(make)

    def _argv(self, job: VideoJob) -> list[str]:
        argv = [*self.command, "--out", str(job.file), "--seconds", f"{job.seconds:g}"]
        argv += ["--width", str(job.width), "--height", str(job.height)]
        if job.clip is not None:
            argv += ["--motion", str(job.clip), "--char", str(job.char)]
        else:
            arg_file = write_arg_file(job.folder / "args.txt", job.configs)
            argv += ["--model_file", str(job.checkpoint), "--arg_file", str(arg_file)]
        data_dir = job.data_dir or self.settings.data_dir
        if data_dir is not None:
            argv += ["--data_dir", str(data_dir)]
        return argv

    def _result(self, job: VideoJob) -> dict[str, Any]:
        if not job.file.is_file():
            raise JobFailed(f"mimickit video exited without writing {VIDEO_FILE}")
        return {"bytes": job.file.stat().st_size}
