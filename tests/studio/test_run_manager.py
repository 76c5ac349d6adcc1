"""The run manager in-process: what a restart finds (gone processes, live ones it adopts), the
registry's atomic creation and an older registry's rows, the trainer command line, end states from
the run folder; reading metrics.jsonl for a browser (non-finite values, a half-written row, the tail)."""

from __future__ import annotations

import json
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mimickit.learning.run_folder import EndState, RunFolder
from mimickit.util.paths import PROJECT_ROOT
from studio.runs.manager import RunManager, end_status, train_command
from studio.runs.metrics import last_rows, read_rows
from studio.runs.registry import Registry, Run, RunStatus
from studio.runs.summary import run_summary
from studio.settings import Settings
from tests.studio.conftest import FAKE_TRAINER, wait_for, write_arg_file

pytestmark = pytest.mark.integration


def settings_for(tmp_path: Path) -> Settings:
    return Settings(runs_dir=tmp_path, trainer=[sys.executable, str(FAKE_TRAINER)], start_viser=False).resolved()


def test_train_command_is_data() -> None:
    config = {"arg_file": "args/a.txt", "rand_seed": 0, "num_envs": 4, "model_file": "/r/1/model.pt", "num_cpus": 2}
    argv = train_command(["mimickit", "train"], config, "/r/1")
    assert argv == ["mimickit", "train", "--arg_file", "args/a.txt", "--out_dir", "/r/1",
                    "--num_envs", "4", "--rand_seed", "0", "--model_file", "/r/1/model.pt"]  # fmt: skip


def test_end_state_comes_from_the_run_folder(tmp_path: Path) -> None:
    reg = Registry(tmp_path / "registry.sqlite")
    run = reg.create("a", {"arg_file": "x"}, lambda i: str(tmp_path / f"{i}"))
    folder = RunFolder(run.out_dir)
    folder.path.mkdir()

    def started(status: RunStatus = RunStatus.RUNNING) -> Run:
        return reg.update(run.id, status=status, started_at=time.time())

    # Nothing recorded: the exit code and the trainer's error line speak.
    folder.console_file.write_text("$ mimickit train ...\nerror: --num_env: unknown argument\n")
    assert end_status(started(), 2) == (RunStatus.FAILED, "--num_env: unknown argument")
    assert end_status(started(), -9) == (RunStatus.FAILED, "the trainer was killed by SIGKILL")
    assert end_status(started(RunStatus.STOPPING), -9) == (RunStatus.STOPPED, None)
    # What the trainer wrote wins over a zero exit code and over a stop that came too late.
    run = started()
    folder.write_state(EndState.DIVERGED, "diverged at iteration 4: critic loss is nan")
    assert end_status(run, 0) == (RunStatus.DIVERGED, "diverged at iteration 4: critic loss is nan")
    folder.write_state(EndState.FINISHED)
    assert end_status(reg.update(run.id, status=RunStatus.STOPPING), 0) == (RunStatus.FINISHED, None)
    # A state.json older than this process is a previous attempt's: not this one's end.
    time.sleep(0.01)
    assert end_status(started(), 2)[0] == RunStatus.FAILED
    folder.write_state(EndState.RUNNING)
    with folder.console_file.open("a") as console:  # a new process: the old error line is not its
        console.write("$ mimickit train ... --model_file model.pt\n")
    assert end_status(reg.get(run.id), 0) == (
        RunStatus.FAILED, "the trainer exited with code 0 without recording why"
    )  # fmt: skip


def test_registry_creates_runs_with_their_folder(tmp_path: Path) -> None:
    reg = Registry(tmp_path / "registry.sqlite")
    run = reg.create("a", {"arg_file": "x"}, lambda i: f"/runs/{i:04d}-a")
    assert run.out_dir == "/runs/0001-a" and run.status == RunStatus.QUEUED
    assert reg.update(run.id, status=RunStatus.RUNNING, pid=5).status == RunStatus.RUNNING
    assert Registry(tmp_path / "registry.sqlite").get(run.id).pid == 5  # on disk, for the next server
    reg.delete(run.id)
    assert reg.find(run.id) is None


def test_restart_marks_gone_processes_interrupted(tmp_path: Path) -> None:
    reg = Registry(tmp_path / "registry.sqlite")
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    a = reg.create("a", {"arg_file": "x"}, lambda i: str(tmp_path / f"{i}"))
    b = reg.create("b", {"arg_file": "x"}, lambda i: str(tmp_path / f"{i}"))
    reg.update(a.id, status=RunStatus.RUNNING, pid=gone.pid)
    reg.update(b.id, status=RunStatus.STOPPING, pid=gone.pid)
    manager = RunManager(settings_for(tmp_path), reg)
    try:
        assert reg.get(a.id).status == RunStatus.INTERRUPTED and reg.get(a.id).pid is None
        assert reg.get(b.id).status == RunStatus.STOPPED  # it was asked to stop; it did
    finally:
        manager.close()


def test_restart_adopts_a_live_trainer_and_can_stop_it(tmp_path: Path) -> None:
    reg = Registry(tmp_path / "registry.sqlite")
    arg = write_arg_file(tmp_path, "long", rows=200, period=0.1)
    run = reg.create("live", {"arg_file": str(arg)}, lambda i: str(tmp_path / f"{i:04d}-live"))
    proc = subprocess.Popen(
        [sys.executable, str(FAKE_TRAINER), "--arg_file", str(arg), "--out_dir", run.out_dir], start_new_session=True
    )
    reg.update(run.id, status=RunStatus.RUNNING, pid=proc.pid)
    manager = RunManager(settings_for(tmp_path), reg)
    try:
        # Going (its first row written, so its SIGTERM handler is in place), and still a running run.
        wait_for(lambda: (Path(run.out_dir) / "metrics.jsonl").is_file(), 30, "the trainer's first row")
        assert reg.get(run.id).status == RunStatus.RUNNING  # a previous server's trainer, still going
        assert manager.stop(run.id).status == RunStatus.STOPPING
        proc.wait(10)  # we are its parent here; a real adopted process is reaped by init
        wait_for(lambda: reg.get(run.id).status == RunStatus.STOPPED, 5, "the adopted run to stop")
        assert (Path(run.out_dir) / "model.pt").is_file()
    finally:
        manager.close()


def test_a_sweep_groups_its_runs(tmp_path: Path) -> None:
    reg = Registry(tmp_path / "registry.sqlite")
    sweep = reg.create_sweep("seeds", {"values": {"rand_seed": [1, 2]}})
    runs = [reg.create(f"s{i}", {"arg_file": "x"}, lambda i: str(tmp_path / f"{i}"), sweep_id=sweep) for i in (1, 2)]
    reg.create("alone", {"arg_file": "x"}, lambda i: str(tmp_path / f"{i}"))
    (listed,) = reg.sweeps()
    assert (listed["id"], listed["name"], listed["run_ids"]) == (sweep, "seeds", [r.id for r in runs])
    assert listed["spec"] == {"values": {"rand_seed": [1, 2]}}


def test_a_run_that_cannot_start_fails_with_the_executors_line(tmp_path: Path) -> None:
    settings = settings_for(tmp_path)
    settings.trainer = [str(tmp_path / "no-such-trainer")]
    reg = Registry(tmp_path / "registry.sqlite")
    manager = RunManager(settings, reg)
    try:
        run = manager.submit("x", {"arg_file": str(write_arg_file(tmp_path, "a"))})
        failed = wait_for(lambda: (r := reg.get(run.id)).status == RunStatus.FAILED and r, 10, "the run to fail")
        assert failed.reason.startswith("local executor could not start it: [Errno 2] No such file")
        assert "could not start" in RunFolder(failed.out_dir).console_file.read_text()
    finally:
        manager.close()


def test_an_older_registry_opens_with_its_rows(tmp_path: Path) -> None:
    """A registry written before runs had a reason column and ended "succeeded"."""
    path = tmp_path / "registry.sqlite"
    with sqlite3.connect(path) as db:
        db.execute(
            "CREATE TABLE runs (id INTEGER PRIMARY KEY AUTOINCREMENT, name TEXT NOT NULL, config TEXT NOT NULL,"
            " status TEXT NOT NULL, pid INTEGER, created_at REAL NOT NULL, started_at REAL, ended_at REAL,"
            " out_dir TEXT NOT NULL, exit_code INTEGER, command TEXT, attempts INTEGER NOT NULL DEFAULT 0)"
        )
        db.execute(
            "INSERT INTO runs (name, config, status, created_at, out_dir, exit_code) VALUES (?, ?, ?, ?, ?, ?)",
            ("old", json.dumps({"arg_file": "x"}), "succeeded", 1.0, str(tmp_path / "1"), 0),
        )
    db.close()
    reg = Registry(path)
    run = reg.get(1)
    assert (run.status, run.reason, run.exit_code) == (RunStatus.FINISHED, None, 0)
    assert (run.executor, run.job_id, run.sweep_id) == ("local", None, None)  # columns added since
    assert reg.update(1, reason="why").reason == "why"
    assert reg.sweeps() == []


def test_metrics_rows_reach_a_browser_as_json_it_parses(tmp_path: Path) -> None:
    path = tmp_path / "metrics.jsonl"
    path.write_text(
        '{"iteration": 0, "samples": 128, "critic_loss": 1.5}\n'
        '{"event": "resume", "iteration": 1, "samples": 128}\n'
        '{"iteration": 1, "samples": 256, "critic_loss": NaN, "actor_loss": Infinity, "adv_std": -Infinity}\n'
        "not json\n"
        '{"iteration": 2, "samp'  # half written: left for later
    )
    rows = read_rows(path)
    assert rows[0] == {"iteration": 0, "samples": 128, "critic_loss": 1.5} and rows[1]["event"] == "resume"
    assert rows[2] == {
        "iteration": 1, "samples": 256, "critic_loss": None, "actor_loss": None, "adv_std": None,
        "nonfinite": {"critic_loss": "nan", "actor_loss": "inf", "adv_std": "-inf"},
    }  # fmt: skip
    assert len(rows) == 3 and json.dumps(rows, allow_nan=False)  # strict JSON, as a browser parses it
    assert last_rows(path, 2) == rows[1:] and read_rows(path, start=2) == rows[2:]


def test_last_rows_reads_the_tail_of_a_long_file(tmp_path: Path) -> None:
    path = tmp_path / "metrics.jsonl"
    row = {"iteration": 0, "samples": 0, "padding": "x" * 1000}
    with path.open("w") as f:
        for i in range(1000):  # ~1 MB: more than the tail that is read
            f.write(json.dumps({**row, "iteration": i}) + "\n")
    assert [r["iteration"] for r in last_rows(path, 3)] == [997, 998, 999]
    tail = last_rows(path, 10_000)  # only whole rows from the tail, none cut at its start
    assert tail[-1]["iteration"] == 999 and all(r["padding"] == row["padding"] for r in tail)
    assert 100 < len(tail) < 1000
    assert last_rows(tmp_path / "missing.jsonl") == []


@pytest.mark.parametrize(
    "bad",
    [["--num_env", "8"], ["--num_envs", "0"], ["--rand_seed", "soon"], ["--model_file", "/no/such/model.pt"]],
    ids=["typo", "zero-envs", "seed-not-a-number", "missing-model"],
)
def test_the_stand_in_refuses_what_the_trainer_refuses(tmp_path: Path, bad: list[str]) -> None:
    """Same argv to `mimickit train` and to the stand-in: the same exit code 2 and `error:` line."""
    argv = ["--arg_file", str(PROJECT_ROOT / "args" / "deepmimic_humanoid_demo_ppo_args.txt")]
    argv += ["--out_dir", str(tmp_path / "run"), *bad]
    real = subprocess.run([sys.executable, "-m", "mimickit.cli", "train", *argv], capture_output=True, text=True)
    fake = subprocess.run([sys.executable, str(FAKE_TRAINER), *argv], capture_output=True, text=True)
    assert real.returncode == fake.returncode == 2
    assert fake.stderr.strip() == real.stderr.strip() and real.stderr.startswith("error: ")
    assert not (tmp_path / "run").exists()


def test_summary_reads_the_env_config_through_the_bounded_loader(tmp_path: Path) -> None:
    """A run folder's yaml is hostile input too: one over the yaml size limit is not parsed."""
    folder = RunFolder(tmp_path)
    folder.config_file("env").write_text("env:\n  motion_file: clip.pkl\n" + "#" * (9 << 20) + "\n")
    assert run_summary(tmp_path)["motion_file"] is None
    folder.config_file("env").write_text("env:\n  motion_file: other.pkl\n")
    assert run_summary(tmp_path)["motion_file"] == "other.pkl"
