"""The run manager: the registry's queued runs started through an executor, followed to their end.

Every run's process (`mimickit train ...`) works in and writes to its run folder (`mimickit.run_folder`:
args.json, configs, metrics.jsonl, model.pt, state.json; console.log with its output). The executor
(`studio.executors`: local subprocesses or Ray jobs) starts, stops and reports on the processes; this
manager keeps the registry's status in step. With the local executor it also keeps the queue (at most
`--max-concurrent-runs` at once); Ray takes every queued run at once and queues them itself. When a
process ends, the run's end state (finished / stopped / diverged / failed, with the line that says why)
is the one its state.json records; the exit code only speaks when the trainer recorded nothing. One
manager thread submits and polls all jobs. A new server re-attaches to the jobs its registry names that
are still going and marks the gone ones `interrupted`, ready to resume.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any

from mimickit.run_args import MULTI_VALUE_ARGS
from mimickit.run_folder import MODEL_FILE, EndState, RunFolder
from mimickit.util.paths import IMPORT_ROOT
from studio.executors import Executor, Job, JobState, Launch, make_executor
from studio.registry import ACTIVE, Registry, Run, RunStatus
from studio.run_summary import run_summary, seed_of
from studio.settings import Settings

CHECKPOINT = MODEL_FILE
POLL_S = 0.2


class RunError(Exception):
    """A run request that cannot be done now (HTTP 409) or names nothing (404)."""

    def __init__(self, message: str, status: int = 409) -> None:
        super().__init__(message)
        self.status = status


def train_command(
    trainer: list[str],
    arg_file: str | Path,
    out_dir: str | Path,
    *,
    num_envs: int | None = None,
    max_samples: int | None = None,
    motion_file: str | None = None,
    rand_seed: int | None = None,
    max_hours: float | None = None,
    data_dir: str | Path | None = None,
    model_file: str | Path | None = None,
    extra: dict[str, str] | None = None,
) -> list[str]:
    """The argv of one training process: `trainer` (`mimickit train`) plus MimicKit's arguments
    (`extra`: further `--key value` pairs, e.g. a sweep's)."""
    argv = [*trainer, "--arg_file", str(arg_file), "--out_dir", str(out_dir)]
    optional = {
        "num_envs": num_envs,
        "max_samples": max_samples,
        "max_hours": max_hours,
        "motion_file": motion_file,
        "rand_seed": rand_seed,
        "data_dir": data_dir,
        "model_file": model_file,
    }
    for key, value in {**optional, **(extra or {})}.items():
        if value is not None:  # "cpu cpu" for --devices: one argv item per value, as a shell would split it
            argv += [f"--{key}", *(str(value).split() if key in MULTI_VALUE_ARGS else [str(value)])]
    return argv


def _resume_budget(
    run: Run, config: dict[str, Any], max_samples: int | None, max_hours: float | None
) -> dict[str, Any]:
    """`config` with the new budgets, after refusing one that is not more than the run has trained, and a
    kept one that is spent (the trainer would refuse it: said here, not as a failed run)."""
    summary = run_summary(run.out_dir)
    done, hours = summary["samples"] or 0, (summary["elapsed_s"] or 0.0) / 3600.0
    given = {k: v for k, v in (("max_samples", max_samples), ("max_hours", max_hours)) if v is not None}
    if not given and run.status == RunStatus.FINISHED:
        raise RunError(
            f"run {run.id} reached its budget ({done} samples, {hours:.3f} h); give a larger max_samples"
            " or max_hours to continue it"
        )
    config = {**config, **given}
    checks = (("max_samples", done, f"{done} samples"), ("max_hours", hours, f"{hours:.3f} h"))
    for key, amount, trained in sorted(checks, key=lambda c: c[0] not in given):  # a given budget's line first
        budget = config.get(key)
        if budget is None or budget > amount:
            continue
        text = f"{budget:g}" if isinstance(budget, float) else str(budget)
        if key in given:
            raise RunError(f"{key} {text} is not more than the {trained} run {run.id} has trained")
        raise RunError(f"run {run.id} has trained {trained}, its {key} {text}; give a larger {key} to continue it")
    return config


def child_env() -> dict[str, str]:
    """What a studio child process (a trainer, an eval) adds to the server's environment: unbuffered
    output, and this `mimickit` first on its path, whatever folder it runs in."""
    path = os.pathsep.join(p for p in (str(IMPORT_ROOT), os.environ.get("PYTHONPATH", "")) if p)
    return {"PYTHONUNBUFFERED": "1", "PYTHONPATH": path}


class RunManager:
    def __init__(self, settings: Settings, registry: Registry, executor: Executor | None = None) -> None:
        self.settings = settings
        self.registry = registry
        self.executor = executor or make_executor(settings)
        self._jobs: dict[int, str] = {}  # run id -> job id of its submitted (pending or running) process
        self._lock = threading.RLock()
        self._wake = threading.Event()
        self._closed = threading.Event()
        self._recover()
        self._thread = threading.Thread(target=self._loop, name="run-manager", daemon=True)
        self._thread.start()

    # -- requests (any thread) ----------------------------------------------------------------------

    def submit(self, name: str, config: dict[str, Any], sweep_id: int | None = None) -> Run:
        """Queue a new run; it starts as soon as a slot is free (local) or Ray has its resources."""
        run = self.registry.create(
            name,
            config,
            lambda i: str(self.settings.runs_dir / f"{i:04d}-{_slug(name)}"),
            executor=self.executor.name,
            sweep_id=sweep_id,
        )
        self._wake.set()
        return run

    def stop(self, run_id: int) -> Run:
        """Not submitted: never starts. Submitted: the executor's stop (SIGTERM, the trainer checkpoints
        and exits; SIGKILL after the stop timeout)."""
        with self._lock:
            run = self.get(run_id)
            job_id = self._jobs.get(run_id)
            if run.status == RunStatus.QUEUED and job_id is None:
                return self.registry.update(run_id, status=RunStatus.STOPPED, ended_at=time.time())
            if run.status not in (*ACTIVE, RunStatus.QUEUED):
                raise RunError(f"run {run_id} is {run.status.value}, not running")
            if run.status != RunStatus.STOPPING:
                run = self.registry.update(run_id, status=RunStatus.STOPPING)
                if job_id is not None:
                    self.executor.stop(job_id)
            return run

    def resume(self, run_id: int, max_samples: int | None = None, max_hours: float | None = None) -> Run:
        """Queue an ended run again: a new process (a new job) in the same folder, from its checkpoint,
        with the budgets `max_samples` (total samples, more than it has trained) and `max_hours` (hours of
        recorded wall time in all, more than it has trained) or those it had."""
        with self._lock:
            run = self.get(run_id)
            if not run.status.finished:
                raise RunError(f"run {run_id} is {run.status.value}; only a run that ended can be resumed")
            checkpoint = RunFolder(run.out_dir).model_file
            if not checkpoint.is_file():
                raise RunError(f"run {run_id} has no checkpoint ({CHECKPOINT}) to resume from")
            config = {**run.config, "model_file": str(checkpoint)}
            config = _resume_budget(run, config, max_samples, max_hours)
            run = self.registry.update(
                run_id,
                status=RunStatus.QUEUED,
                config=config,
                pid=None,
                job_id=None,
                exit_code=None,
                ended_at=None,
                reason=None,
                executor=self.executor.name,
            )
        self._wake.set()
        return run

    def again(self, run_id: int) -> Run:
        """A new run with the same arg file and overrides as run `run_id`, and the seed it used."""
        run = self.get(run_id)
        seed = seed_of(run.out_dir)
        if seed is None:
            raise RunError(f"run {run_id} recorded no seed (its trainer wrote no args.json yet)")
        config = {k: v for k, v in run.config.items() if k != "model_file"}
        return self.submit(f"{run.name} seed {seed}", {**config, "rand_seed": seed})

    def delete(self, run_id: int) -> None:
        """Remove the row and the run's folder (only ever a folder inside the runs folder)."""
        with self._lock:
            run = self.get(run_id)
            if run.status in ACTIVE or run_id in self._jobs:
                raise RunError(f"run {run_id} is {run.status.value}; stop it before deleting it")
            self.registry.delete(run_id)
        out_dir = Path(run.out_dir).resolve() if run.out_dir else None
        runs_dir = self.settings.runs_dir.resolve()
        if out_dir and out_dir != runs_dir and out_dir.is_relative_to(runs_dir) and out_dir.is_dir():
            shutil.rmtree(out_dir, ignore_errors=True)

    def logs(self, run_id: int) -> str:
        """The output of the run's latest process: the executor's (Ray keeps a job's log while it
        runs) or, once ended or with the local executor, the run folder's console.log."""
        run = self.get(run_id)
        job_id = self._jobs.get(run_id)
        text = self.executor.logs(job_id) if job_id is not None else None
        if text is not None:
            return text
        path = RunFolder(run.out_dir).console_file
        return path.read_text(errors="replace") if path.is_file() else ""

    def close(self) -> None:
        self._closed.set()
        self._wake.set()
        self._thread.join(timeout=5)
        self.executor.close()

    # -- the manager thread ---------------------------------------------------------------------------

    def _loop(self) -> None:
        while not self._closed.is_set():
            try:
                with self._lock:
                    self._poll()
                    self._fill_slots()
            except Exception as e:  # keep managing the other runs; the error goes to the server log
                print(f"run manager: {e!r}", file=sys.stderr)
            self._wake.wait(POLL_S)
            self._wake.clear()

    def _poll(self) -> None:
        for run_id, job_id in list(self._jobs.items()):
            run = self.registry.find(run_id)
            job = self.executor.status(job_id, run.out_dir if run else "")
            if run is None:
                del self._jobs[run_id]
            elif job is None or job.state == JobState.ENDED:
                del self._jobs[run_id]
                self._finish(run, job)
            elif job.state == JobState.RUNNING and run.status == RunStatus.QUEUED:
                self.registry.update(run_id, status=RunStatus.RUNNING, started_at=job.started_at or time.time())

    def _finish(self, run: Run, job: Job | None) -> None:
        """Status from the run folder's state.json; `job` None: a process no executor knows now."""
        if job is not None and run.status == RunStatus.QUEUED:  # ended between two polls
            run = self.registry.update(run.id, started_at=job.started_at or run.created_at)
        logs = self.executor.logs(run.job_id) if run.job_id else None
        if logs:  # Ray's log of the job: kept with the run, where a local process writes its output
            _append(RunFolder(run.out_dir).console_file, logs)
        code = job.exit_code if job else None
        status, reason = end_status(run, code)
        if reason is None and job is not None and job.message and status == RunStatus.FAILED:
            reason = job.message
        ended = job.ended_at if job and job.ended_at else time.time()
        self.registry.update(run.id, status=status, reason=reason, exit_code=code, ended_at=ended, pid=None)

    def _fill_slots(self) -> None:
        active = len(self._jobs)
        for run in self.registry.list(RunStatus.QUEUED):
            if run.id in self._jobs:
                continue
            if not self.executor.queues and active >= self.settings.max_concurrent_runs:
                return
            self._start(run)
            active += 1

    def _start(self, run: Run) -> None:
        if not run.out_dir:  # never run a trainer in the server's working directory
            self.registry.update(run.id, status=RunStatus.FAILED, ended_at=time.time())
            return
        launch = self._launch(run)
        launch.work_dir.mkdir(parents=True, exist_ok=True)
        _append(launch.console_file, f"$ {' '.join(launch.argv)}\n")
        try:
            job_id = self.executor.submit(launch)
        except Exception as e:  # the executor's refusal (no such program, Ray unreachable): the run's reason
            _append(launch.console_file, f"could not start: {e}\n")
            reason = f"{self.executor.name} executor could not start it: {str(e).strip().splitlines()[0][:300]}"
            self.registry.update(
                run.id, status=RunStatus.FAILED, ended_at=time.time(), command=launch.argv, reason=reason
            )
            return
        self._jobs[run.id] = job_id
        queued = self.executor.queues  # a Ray job stays `queued` until Ray reports it running
        self.registry.update(
            run.id,
            status=RunStatus.QUEUED if queued else RunStatus.RUNNING,
            pid=None if queued else int(job_id),
            job_id=job_id,
            executor=self.executor.name,
            started_at=None if queued else time.time(),
            command=launch.argv,
            attempts=run.attempts + 1,
        )

    def _launch(self, run: Run) -> Launch:
        """What the executor starts for `run`: the trainer working in its run folder (MuJoCo's
        MUJOCO_LOG.TXT and the like land there, not in the server's directory), with the project
        importable for `python -m mimickit.cli`."""
        cfg = run.config
        out_dir = Path(run.out_dir)
        argv = train_command(
            self.settings.trainer,
            cfg["arg_file"],
            out_dir,
            num_envs=cfg.get("num_envs"),
            max_samples=cfg.get("max_samples"),
            motion_file=cfg.get("motion_file"),
            rand_seed=cfg.get("rand_seed"),
            max_hours=cfg.get("max_hours"),
            data_dir=self.settings.data_dir,
            model_file=cfg.get("model_file"),
            extra=cfg.get("args"),
        )
        return Launch(
            argv=argv,
            work_dir=out_dir,
            console_file=RunFolder(out_dir).console_file,
            env=child_env(),
            num_cpus=cfg.get("num_cpus"),
            num_gpus=cfg.get("num_gpus"),
            name=f"{run.id}: {run.name}",
        )

    # -- start-up ----------------------------------------------------------------------------------

    def _recover(self) -> None:
        """Runs a previous server left submitted: re-attach to the jobs still going, end the rest."""
        for run in self.registry.list():
            job_id = run.job_id or (str(run.pid) if run.pid else None)
            if run.status not in ACTIVE and not (run.status == RunStatus.QUEUED and job_id):
                continue
            job = self.executor.status(job_id, run.out_dir) if job_id and run.executor == self.executor.name else None
            if job is not None and job.state != JobState.ENDED:
                self._jobs[run.id] = job_id
            elif job is not None:
                self._finish(run, job)
            elif run.status == RunStatus.QUEUED:  # its job is gone before it started: submit it again
                self.registry.update(run.id, job_id=None)
            elif run.status == RunStatus.STOPPING:
                self.registry.update(run.id, status=RunStatus.STOPPED, ended_at=time.time(), pid=None)
            else:
                self.registry.update(run.id, status=RunStatus.INTERRUPTED, ended_at=time.time(), pid=None)

    # -- helpers -----------------------------------------------------------------------------------------

    def get(self, run_id: int) -> Run:
        """The run, or RunError 404."""
        run = self.registry.find(run_id)
        if run is None:
            raise RunError(f"no run {run_id}", 404)
        return run


def end_status(run: Run, code: int | None) -> tuple[RunStatus, str | None]:
    """How a run's latest process ended: its state.json (when written by that process), else a stop
    the studio asked for, else the exit code (with the trainer's `error: ...` line as the reason)."""
    folder = RunFolder(run.out_dir)
    state = folder.read_state()
    if state is not None and state.state != EndState.RUNNING and state.updated_at >= (run.started_at or 0.0):
        return RunStatus(state.state.value), state.reason or None
    if run.status == RunStatus.STOPPING:
        return RunStatus.STOPPED, None
    if code is None:
        return RunStatus.INTERRUPTED, "its trainer ended while no studio watched it, without recording why"
    if code < 0:
        return RunStatus.FAILED, f"the trainer was killed by {_signal_name(-code)}"
    return RunStatus.FAILED, _error_line(folder) or f"the trainer exited with code {code} without recording why"


def _error_line(folder: RunFolder) -> str | None:
    """The latest process's last `error: ...` line in console.log (how `mimickit` reports a mistake);
    each process's output starts with the `$ argv` line the manager writes."""
    try:
        with folder.console_file.open("rb") as f:
            f.seek(max(0, f.seek(0, 2) - 64 * 1024))
            lines = f.read().decode(errors="replace").splitlines()
    except OSError:
        return None
    starts = [i for i, line in enumerate(lines) if line.startswith("$ ")]
    lines = lines[starts[-1] :] if starts else lines
    errors = [line.strip() for line in lines if line.startswith("error: ")]
    return errors[-1][len("error: ") :] if errors else None


def _signal_name(signum: int) -> str:
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "-", name).strip("-.")[:40] or "run"


def _append(path: Path, text: str) -> None:
    with open(path, "a", encoding="utf-8", errors="replace") as f:
        f.write(text)
