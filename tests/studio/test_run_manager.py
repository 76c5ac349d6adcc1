"""The run manager in-process: what a restart finds (gone processes, live ones it adopts), the
registry's atomic creation, the trainer command line."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

from mimickit.run_folder import EndState, RunFolder
from studio.registry import Registry, Run, RunStatus
from studio.runs import RunManager, end_status, train_command
from studio.settings import Settings
from tests.studio.conftest import FAKE_TRAINER, wait_for, write_arg_file


def settings_for(tmp_path: Path) -> Settings:
    return Settings(runs_dir=tmp_path, trainer=[sys.executable, str(FAKE_TRAINER)], start_viser=False).resolved()


def test_train_command_is_data() -> None:
    argv = train_command(
        ["mimickit", "train"], "args/a.txt", "/r/1", num_envs=4, rand_seed=0, model_file="/r/1/model.pt"
    )
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
