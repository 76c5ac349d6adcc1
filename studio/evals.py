"""Evaluation jobs: `mimickit eval --json` on a checkpoint, as a background subprocess per job.

A job runs in its own folder, `<runs-dir>/evals/<id>/` (its working directory: MuJoCo's log and the
like land there, not in the server's), with the arg file it was given or, for a run's checkpoint, one
written there naming the configs the trainer copied beside the checkpoint. The command's stdout (the
JSON report) and stderr go to files in that folder; one worker thread runs the jobs one after another
(an eval takes the cores a training needs) and parses the report, so no request waits on it. A job
that fails says why in one line: `mimickit`'s own `error:` line, else the last line it printed.
`stop` ends a queued job before it starts and kills a running one's process group; `remove` forgets an
ended job and deletes its folder.

The queue, the worker and the job records are `studio/job_queue.py`'s: each job's `job.json` (its
request, status, times, rows and mean) lets a restarted server list the jobs of the one before.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from mimickit.util.errors import MimicKitError
from studio.job_process import failure_line
from studio.job_queue import ACTIVE, Job, JobQueue
from studio.library import one_line
from studio.settings import Settings

__all__ = ["ACTIVE", "EVALS_DIR", "EvalJob", "EvalJobs", "clip_env_config"]

EVALS_DIR = "evals"
EVAL_COMMAND = [sys.executable, "-m", "mimickit.cli", "eval"]


@dataclass(kw_only=True)
class EvalJob(Job):
    PATH_FIELDS = ("folder", "checkpoint", "arg_file")

    checkpoint: Path
    arg_file: Path
    motion_file: str | None = None
    episodes: int = 8
    run_id: int | None = None
    rows: list[dict[str, Any]] = field(default_factory=list)
    mean: dict[str, Any] | None = None

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


class EvalJobs(JobQueue[EvalJob]):
    """The eval jobs under `<runs-dir>/evals/` and the worker thread that runs them."""

    job_type = EvalJob
    cannot_run = "could not run the eval"

    def __init__(self, settings: Settings, command: list[str] | None = None) -> None:
        self.settings = settings
        self.command = list(command or EVAL_COMMAND)
        super().__init__(settings.runs_dir / EVALS_DIR, "evals")

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

        def make(job_id: int, folder: Path) -> EvalJob:
            args = arg_file
            if args is None:
                args = folder / "args.txt"
                args.write_text("".join(f"--{k} {v}\n" for k, v in configs.items() if v is not None))
            job = EvalJob(
                id=job_id,
                folder=folder,
                checkpoint=checkpoint,
                arg_file=args,
                motion_file=motion_file,
                episodes=episodes,
                run_id=run_id,
            )
            job.command = self._argv(job)
            return job

        return self._add(make)

    def _argv(self, job: EvalJob) -> list[str]:
        argv = [*self.command, "--arg_file", str(job.arg_file), "--model_file", str(job.checkpoint)]
        argv += ["--episodes", str(job.episodes), "--json"]
        if job.motion_file:
            argv += ["--motion_file", job.motion_file]
        if self.settings.data_dir is not None:
            argv += ["--data_dir", str(self.settings.data_dir)]
        return argv

    def _run(self, job: EvalJob) -> None:
        out_path, err_path = job.folder / "report.json", job.folder / "console.log"
        with open(out_path, "wb") as out, open(err_path, "wb") as err:
            proc = self._launch(job, out, err)
            if proc is None:
                return
            code = self._wait(proc)
        if job.status != "running":  # stopped meanwhile
            return
        if code != 0:
            self._end(job, "failed", failure_line("mimickit eval", err_path, code))
            return
        try:
            report = json.loads(out_path.read_text())
            rows, mean = list(report["rows"]), report["mean"]
        except (ValueError, KeyError, TypeError) as e:
            self._end(job, "failed", one_line(f"mimickit eval printed no report ({type(e).__name__}: {e})"))
            return
        self._end(job, "finished", rows=rows, mean=mean)


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
