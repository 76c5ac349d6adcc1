"""Evaluation jobs: `mimickit eval --json` on a checkpoint, as a background subprocess per job on
the shared job queue (`studio/jobs/queue.py`: its folder `<runs-dir>/evals/<id>/`, one worker thread,
records a restarted server lists, `stop` and `remove`).

A job runs with the arg file it was given or, for a run's checkpoint, one written into its folder naming
the configs the trainer copied beside the checkpoint. The command's stdout (the JSON report) goes to
`report.json`; its rows and their mean are the job's result.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from mimickit.util.errors import MimicKitError
from studio.jobs.queue import ACTIVE, Job, JobFailed, JobQueue, write_arg_file
from studio.settings import Settings

__all__ = ["ACTIVE", "EVALS_DIR", "EvalJob", "EvalJobs", "clip_env_config"]

EVALS_DIR = "evals"
EVAL_COMMAND = [sys.executable, "-m", "mimickit.cli", "eval"]
REPORT_FILE = "report.json"


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
            **super().to_json(),
            "checkpoint": str(self.checkpoint),
            "arg_file": str(self.arg_file),
            "motion_file": self.motion_file,
            "episodes": self.episodes,
            "run_id": self.run_id,
            "rows": self.rows,
            "mean": self.mean,
        }


class EvalJobs(JobQueue[EvalJob]):
    """The eval jobs under `<runs-dir>/evals/` and the worker thread that runs them."""

    job_type = EvalJob
    kind = "eval"
    cannot_run = "could not run the eval"
    folder_name = EVALS_DIR
    program = "mimickit eval"
    default_command = EVAL_COMMAND
    stdout_file = REPORT_FILE

    def _time_limit(self, settings: Settings) -> float:
        return settings.eval_time_limit_s

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
                args = write_arg_file(folder / "args.txt", configs)
            return EvalJob(
                id=job_id,
                folder=folder,
                checkpoint=checkpoint,
                arg_file=args,
                motion_file=motion_file,
                episodes=episodes,
                run_id=run_id,
            )

        return self._add(make)

    def _argv(self, job: EvalJob) -> list[str]:
        argv = [*self.command, "--arg_file", str(job.arg_file), "--model_file", str(job.checkpoint)]
        argv += ["--episodes", str(job.episodes), "--json"]
        if job.motion_file:
            argv += ["--motion_file", job.motion_file]
        if self.settings.data_dir is not None:
            argv += ["--data_dir", str(self.settings.data_dir)]
        return argv

    def _result(self, job: EvalJob) -> dict[str, Any]:
        try:
            report = json.loads((job.folder / REPORT_FILE).read_text())
            return {"rows": list(report["rows"]), "mean": report["mean"]}
        except (ValueError, KeyError, TypeError) as e:
            raise JobFailed(f"mimickit eval printed no report ({type(e).__name__}: {e})") from None


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
