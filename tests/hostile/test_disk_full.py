"""A full or read-only disk, for real: a tiny tmpfs filled to its last page (or mounted read-only) under
a trainer's run folder and under a real `mimickit-studio serve`'s runs folder.

Every writer answers one line (`error: ...` from the trainer; HTTP 507 / 503 `{"detail": "one line"}`
from the studio), never a traceback or an HTTP 500; the server keeps answering reads; a run that
failed for want of space says so in its state.json and in the studio; the previous model.pt stays
whole. Mounting needs root (CI containers run the suite as root); elsewhere these cases skip.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from mimickit.learning.checkpoint import read_checkpoint
from mimickit.learning.run_folder import EndState, RunFolder
from tests.conftest import DEMO_CLIP
from tests.studio.conftest import REAL_TRAINER, TRAINER, StudioProcess, wait_for, write_arg_file
from tests.test_cli_train import ARG_FILE, mimickit, train_args

pytestmark = pytest.mark.integration

SAMPLES_PER_ITER = 4 * 32  # test_cli_train's NUM_ENVS 4 × 32 steps per iteration
ENDLESS = str(SAMPLES_PER_ITER * 100_000)  # a budget the disk runs out long before
NO_SPACE = os.strerror(errno.ENOSPC)


def one_case(case_id: str) -> pytest.MarkDecorator:
    """A single case with its `err-`/`ok-` id, so the suite counts it like the parametrized ones."""
    return pytest.mark.parametrize("case", [case_id], ids=[case_id])


@contextlib.contextmanager
def tmpfs(path: Path, size: str) -> Iterator[Path]:
    """`path` as a fresh tmpfs of `size` (e.g. "16m"); the case skips where mounting is not allowed."""
    path.mkdir(parents=True, exist_ok=True)
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)], capture_output=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs (needs root): {r.stderr.decode(errors='replace').strip()[:200]}")
    try:
        yield path
    finally:  # lazily: a process that still holds a file there must not keep the mount
        subprocess.run(["umount", "-l", str(path)], check=True)


def fill(disk: Path) -> None:
    """Take every free byte of `disk`: a filler file written until the disk says it is full."""
    fd = os.open(disk / "filler", os.O_WRONLY | os.O_CREAT | os.O_APPEND)
    chunk = b"\0" * (1 << 16)
    try:
        while True:
            os.write(fd, chunk)
    except OSError as e:
        assert e.errno == errno.ENOSPC, e
    finally:
        os.close(fd)


def metric_rows(folder: Path) -> int:
    path = folder / "metrics.jsonl"
    return len(path.read_text().splitlines()) if path.is_file() else 0


def assert_one_line(response: httpx.Response, status: int, *needles: str) -> str:
    assert response.status_code == status, response.text
    detail = response.json()["detail"]
    assert isinstance(detail, str) and "\n" not in detail and len(detail) < 400, detail
    for needle in needles:
        assert needle in detail, detail
    return detail


class DiskStudio(StudioProcess):
    """`mimickit-studio serve` whose runs folder is `runs_dir` (on the small disk) while its own stderr
    goes to `log_dir` (not on it: the server's log is no part of what is tested)."""

    def __init__(self, runs_dir: Path, log_dir: Path, trainer: str) -> None:
        self.runs_dir = runs_dir
        argv = [sys.executable, "-m", "studio.cli", "serve", "--port", "0", "--viser-port", "0"]
        argv += ["--runs-dir", str(runs_dir), "--trainer", trainer]
        self.stderr_path = log_dir / "server.stderr.log"
        with open(self.stderr_path, "a") as err:
            self.proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=err, text=True)
        self.url = self._read_url()
        self.client = httpx.Client(base_url=self.url, timeout=60.0, headers={"X-Studio-Request": "1"})


@contextlib.contextmanager
def disk_studio(runs_dir: Path, log_dir: Path, trainer: str = TRAINER) -> Iterator[DiskStudio]:
    server = DiskStudio(runs_dir, log_dir, trainer)
    try:
        yield server
    finally:
        server.stop()
        assert "Traceback" not in server.stderr_path.read_text(), server.stderr_path.read_text()[-3000:]


@one_case("err-train-disk-fills-up")
def test_trainer_whose_disk_fills_up_ends_in_one_line_and_a_failed_state(case: str, tmp_path: Path) -> None:
    """A resumed run's disk fills up mid-run: one `error:` line (no traceback), exit 1, state.json
    `failed` with that line (written over the old one: no space for a new file), model.pt untouched."""
    base = tmp_path / "base"
    r = mimickit(*train_args(base, "--max_samples", str(SAMPLES_PER_ITER)))
    assert r.returncode == 0, r.stderr[-2000:]
    with tmpfs(tmp_path / "disk", "16m") as disk:
        run = disk / "run"
        shutil.copytree(base, run)
        model = (run / "model.pt").read_bytes()
        rows = metric_rows(run)
        argv = [sys.executable, "-m", "mimickit.cli", *train_args(run, "--max_samples", ENDLESS)]
        argv += ["--model_file", str(run / "model.pt")]
        with open(tmp_path / "out.log", "w") as out, open(tmp_path / "err.log", "w") as err:
            proc = subprocess.Popen(argv, stdout=out, stderr=err, cwd=ARG_FILE.parents[1])
            try:  # the resume marker and one iteration's row: the run is under way
                wait_for(lambda: proc.poll() is not None or metric_rows(run) >= rows + 2, 240, "a trained iteration")
                fill(disk)
                code = proc.wait(timeout=300)
            finally:
                if proc.poll() is None:
                    proc.kill()
        stderr = (tmp_path / "err.log").read_text()
        assert code == 1, stderr[-2000:]
        assert "Traceback" not in stderr, stderr[-3000:]
        errors = [line for line in stderr.splitlines() if line.startswith("error: ")]
        assert len(errors) == 1 and NO_SPACE in errors[0], stderr[-2000:]
        assert any(str(run / name) in errors[0] for name in ("metrics.jsonl", "log.txt", "model.pt")), errors[0]
        state = RunFolder(run).read_state()
        assert state is not None and state.state == EndState.FAILED, (run / "state.json").read_text()
        assert state.reason == errors[0].removeprefix("error: ")
        assert (run / "model.pt").read_bytes() == model
        assert read_checkpoint(run / "model.pt")


@one_case("err-studio-full-disk")
def test_studio_on_a_full_disk_answers_reads_and_refuses_writes_in_one_line(case: str, tmp_path: Path) -> None:
    """The runs folder's disk is full: the run list, one run and health still answer 200; a launch, a
    sweep, an upload answer 507 in one line; an upload into a read-only folder answers 503."""
    with tmpfs(tmp_path / "runs", "4m") as runs_dir, disk_studio(runs_dir, tmp_path) as server:
        arg_file = write_arg_file(runs_dir, "short", rows=2, period=0.05)
        r = server.post("/api/runs", json={"arg_file": str(arg_file)})
        assert r.status_code == 201, r.text
        run_id = r.json()["id"]
        wait_for(lambda: server.get(f"/api/runs/{run_id}").json()["status"] == "finished", 60, "the run's end")
        with tmpfs(runs_dir / "uploads", "1m") as uploads:
            subprocess.run(["mount", "-o", "remount,ro", str(uploads)], check=True)
            r = server.post("/api/motions/upload", params={"filename": "squat.pkl"}, content=DEMO_CLIP.read_bytes())
            assert_one_line(r, 503, str(uploads / "squat.pkl"), "read-only")
        fill(runs_dir)

        listed = server.get("/api/runs")
        assert listed.status_code == 200, listed.text
        assert [run["id"] for run in listed.json()] == [run_id]
        assert server.get(f"/api/runs/{run_id}").status_code == 200
        assert server.get("/api/health").status_code == 200
        assert_one_line(server.post("/api/runs", json={"arg_file": str(arg_file)}), 507, str(runs_dir), "full")
        sweep = {"arg_file": str(arg_file), "values": {"num_envs": [1, 2]}}
        assert_one_line(server.post("/api/sweeps", json=sweep), 507, str(runs_dir), "full")
        r = server.post("/api/motions/upload", params={"filename": "squat.pkl"}, content=DEMO_CLIP.read_bytes())
        assert_one_line(r, 507, "squat.pkl", "full")
        assert [run["id"] for run in server.get("/api/runs").json()] == [run_id]


@one_case("err-studio-run-disk-fills-up")
def test_studio_records_a_real_run_failed_when_its_disk_fills_up(case: str, tmp_path: Path) -> None:
    """A real trainer launched from the studio; the runs folder's disk fills up mid-run (its console.log
    there too): the run ends `failed` with the line that says so, in the studio and in its state.json."""
    with tmpfs(tmp_path / "runs", "24m") as runs_dir, disk_studio(runs_dir, tmp_path, REAL_TRAINER) as server:
        body = {"arg_file": str(ARG_FILE), "num_envs": 2, "max_samples": int(ENDLESS)}
        r = server.post("/api/runs", json=body)
        assert r.status_code == 201, r.text
        run_id, out_dir = r.json()["id"], Path(r.json()["out_dir"])
        wait_for(lambda: metric_rows(out_dir) >= 1, 240, "a trained iteration")
        fill(runs_dir)
        run = wait_for(lambda: _ended(server, run_id), 300, "the run's end")
        assert run["status"] == "failed" and NO_SPACE in run["reason"], run
        assert "\n" not in run["reason"]
        state = json.loads((out_dir / "state.json").read_text())
        assert state["state"] == "failed" and state["reason"] == run["reason"]
        assert server.get("/api/runs").status_code == 200


def _ended(server: StudioProcess, run_id: int) -> dict | None:
    r = server.get(f"/api/runs/{run_id}")
    assert r.status_code == 200, r.text
    run = r.json()
    return run if run["status"] not in ("queued", "running", "stopping") else None
