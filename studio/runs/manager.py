"""The run manager: the registry's queued runs started through an executor, followed to their end.

Every run's process (`mimickit train ...`) works in and writes to its run folder (`mimickit.learning.run_folder`:
args.json, configs, metrics.jsonl, model.pt, state.json; console.log with its output). The executor
(`studio.runs.executors`: local subprocesses or Ray jobs) starts, stops and reports on the processes; this
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

from mimickit.learning.run_folder import MODEL_FILE, EndState, RunFolder
from mimickit.runner.args import check_run_args
from mimickit.util.arg_parser import ArgParser
from mimickit.util.errors import MimicKitError, shorten
from mimickit.util.paths import IMPORT_ROOT
from studio.disk import disk_error
from studio.runs.executors import Executor, Job, JobState, Launch, make_executor
from studio.runs.launch_fields import TRAINER_FIELDS
from studio.runs.registry import ACTIVE, Registry, Run, RunStatus
from studio.runs.summary import run_summary, seed_of
from studio.settings import Settings

CHECKPOINT = MODEL_FILE
POLL_S = 0.2
RAY_BATCH = 100  # queued runs handed to Ray per manager step (Ray queues them itself)
MAX_VALUE_CHARS = 4096  # an argument value: a path at most
_CUDA_RE = re.compile(r"^cuda(:\d+)?$")


class RunError(Exception):
    """A run request that cannot be done now (HTTP 409) or names nothing (404)."""

    def __init__(self, message: str, status: int = 409) -> None:
        super().__init__(message)
        self.status = status


def train_args(config: dict[str, Any], out_dir: str | Path, data_dir: str | Path | None = None) -> dict[str, list[str]]:
    """MimicKit's arguments of one training process, `key` (no dashes) → its argv items: the arg file,
    the run folder, the launch fields that are the trainer's (`launch_fields.TRAINER_FIELDS`, in their
    order), the data folder, the checkpoint to resume from, and `config["args"]` (further keys, e.g. a
    sweep's; a list is several values, `--devices cpu cpu`)."""
    fields = {f.flag: config.get(f.name) for f in TRAINER_FIELDS if f.name != "arg_file"}
    optional = {**fields, "data_dir": data_dir, "model_file": config.get("model_file"), **(config.get("args") or {})}
    table = {"arg_file": [str(config["arg_file"])], "out_dir": [str(out_dir)]}
    return table | {k: _items(v) for k, v in optional.items() if v is not None}


def train_command(
    trainer: list[str], config: dict[str, Any], out_dir: str | Path, data_dir: str | Path | None = None
) -> list[str]:
    """The argv of one training process: `trainer` (`mimickit train`) plus `train_args`."""
    return [*trainer, *_argv(train_args(config, out_dir, data_dir))]


def _items(value: object) -> list[str]:
    """A value's argv items: each is exactly one (never split on spaces: a value cannot smuggle a key); a
    bool as the trainer's `true`/`false` (a checkbox field's)."""
    if isinstance(value, bool):
        return [str(value).lower()]
    return [str(v) for v in value] if isinstance(value, list) else [str(value)]


def _argv(table: dict[str, list[str]]) -> list[str]:
    return [item for key, values in table.items() for item in (f"--{key}", *values)]


def _run_args(config: dict[str, Any], settings: Settings, out_dir: Path | None = None) -> dict[str, list[str]]:
    """MimicKit's arguments of a run's config (in `out_dir`, else a stand-in: it is not probed)."""
    return train_args(config, out_dir or settings.runs_dir, settings.data_dir)


def _check_value(key: str, value: str) -> None:
    """RunError 400 for a value MimicKit's parser would not read back as that one value (`--x` starts a
    key, `#x` is a comment) or that holds a control character or is longer than any path."""
    probe = ArgParser()
    probe.load_args([f"--{key}", value])
    bad = probe.parse_strings(key) != [value] or probe.all_keys() != [key]
    if bad or len(value) > MAX_VALUE_CHARS or any(ord(c) < 32 or ord(c) == 127 for c in value):
        raise RunError(
            f"--{key}: {shorten(value, 100)!r} is not a value (one argv item, at most {MAX_VALUE_CHARS} characters,"
            " not starting with '--' or '#', no control characters)",
            400,
        )


def _id_text(run_id: int) -> str:
    """An id as an error line quotes it: a number of more than 128 bits by its size only."""
    return str(run_id) if run_id.bit_length() <= 128 else f"(an id of {run_id.bit_length()} bits)"


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

    def submit(self, name: str, config: dict[str, Any]) -> Run:
        """Queue a new run; it starts as soon as a slot is free (local) or Ray has its resources."""
        return self.submit_many([(name, config)])[0]

    def submit_many(
        self, runs: list[tuple[str, dict[str, Any]]], sweep: tuple[str, dict[str, Any]] | None = None
    ) -> list[Run]:
        """Queue each (name, config), all or none: every config is checked as the trainer would check
        its arguments, and the queue must have room for all of them (`max_queued_runs`). `sweep`
        (name, spec): they are the runs of a new sweep (their `sweep_id`)."""
        for _, config in runs:
            self.check_config(config)
        with self._lock:  # the room checked and taken in one step: two launches cannot both fit in one slot
            self._check_room(len(runs))
            sweep_id = self.registry.create_sweep(*sweep) if sweep else None
            created = [
                self.registry.create(
                    name,
                    config,
                    lambda i, name=name: str(self.settings.runs_dir / f"{i:04d}-{_slug(name)}"),
                    executor=self.executor.name,
                    sweep_id=sweep_id,
                )
                for name, config in runs
            ]
        self._wake.set()
        return created

    def check_config(self, config: dict[str, Any]) -> None:
        """RunError 400 with one line for an argument the trainer would refuse, before anything is queued:
        the argv the run would get, read back by MimicKit's parser (each value must stay the one value it
        was given) and checked by `check_run_args`. The arg file is left to the trainer (a custom
        `--trainer` may take keys of its own there); the checkpoint is the studio's own file."""
        table = {k: v for k, v in _run_args(config, self.settings).items() if k not in ("arg_file", "model_file")}
        for key, values in table.items():
            for value in values:
                _check_value(key, value)
        args = ArgParser(self.settings.data_paths)
        args.load_args(_argv(table))
        if self.executor.name == "ray" and args.has_key("devices"):  # the devices are the Ray node's, not ours
            args.set("devices", *(_CUDA_RE.sub("cpu", d) for d in args.parse_strings("devices")))
        try:
            check_run_args(args, probe_out_dir=False)
        except MimicKitError as e:
            raise RunError(str(e), 400) from None

    def _check_room(self, adding: int) -> None:
        queued, cap = self.registry.count(RunStatus.QUEUED), self.settings.max_queued_runs
        if queued + adding > cap:
            raise RunError(
                f"the queue holds {queued} runs and takes at most {cap} (--max-queued-runs); this would add"
                f" {adding}: stop some (POST /api/runs/stop) or wait",
                429,
            )

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
            self.check_config(config)
            self._check_room(1)
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

    def stop_many(self, ids: list[int]) -> dict[str, list[int]]:
        """Stop every run of `ids` at once (404 naming the first that is not a run, before any is
        stopped): the queued ones never start (one registry write for all), the going ones get the
        executor's stop, those that ended already are left as they are."""
        with self._lock:
            runs = self.registry.of_ids(ids)
            missing = sorted(set(ids) - {r.id for r in runs})
            if missing:
                raise RunError(f"no run {_id_text(missing[0])}", 404)
            queued = [r.id for r in runs if r.status == RunStatus.QUEUED and r.id not in self._jobs]
            self.registry.stop_queued(queued, time.time())
            never_started = set(queued)
            going = [r.id for r in runs if r.id not in never_started and not r.status.finished]
            for run_id in going:
                self.stop(run_id)
        return {"stopped": queued, "stopping": going, "ended": [r.id for r in runs if r.status.finished]}

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

    def label(self, run_id: int, tags: list[str] | None = None, notes: str | None = None) -> Run:
        """Set the user's tags and notes of a run, whatever its status (only those given): under the
        manager's lock, so that a delete cannot pass between the check and the write."""
        given = {k: v for k, v in (("tags", tags), ("notes", notes)) if v is not None}
        with self._lock:
            self.get(run_id)
            return self.registry.update(run_id, **given)

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
                self._finish(run, job)
                del self._jobs[run_id]  # once recorded: a registry that cannot write now tries at the next poll
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
        """Start the oldest queued runs while slots are free (local), or hand Ray a batch of them; only
        as many rows are read as can start, so a long queue costs the manager nothing."""
        free = RAY_BATCH if self.executor.queues else self.settings.max_concurrent_runs - len(self._jobs)
        if free <= 0:
            return
        # A run re-attached from an older registry may be in _jobs without a job id: read past those.
        for run in self.registry.unsubmitted(free + len(self._jobs)):
            if free <= 0:
                return
            if run.id not in self._jobs:
                self._start(run)
                free -= 1

    def _start(self, run: Run) -> None:
        if not run.out_dir:  # never run a trainer in the server's working directory
            self.registry.update(run.id, status=RunStatus.FAILED, ended_at=time.time())
            return
        launch = self._launch(run)
        try:
            launch.work_dir.mkdir(parents=True, exist_ok=True)
            _append(launch.console_file, f"$ {' '.join(launch.argv)}\n")
        except OSError as e:  # a full or read-only disk: the run fails with the line that says so
            found = disk_error(e, e.filename or launch.console_file)
            if found is None:
                raise
            self.registry.update(
                run.id, status=RunStatus.FAILED, ended_at=time.time(), command=launch.argv, reason=str(found)
            )
            return
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
        return Launch(
            argv=[*self.settings.trainer, *_argv(_run_args(cfg, self.settings, out_dir))],
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
            raise RunError(f"no run {_id_text(run_id)}", 404)
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
