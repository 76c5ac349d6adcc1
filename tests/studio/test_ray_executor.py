"""Runs on a real Ray cluster: a local Ray head (2 CPUs, its own temp dir and free ports) started once
for this file and stopped at its end, and studios serving with `--executor ray`. A run launched from the
API becomes a Ray job, streams metrics, stops with its checkpoint and resumes as a new job in the same
folder; a restarted studio keeps a running job attached; a 4-run sweep of 1 CPU each runs 2 at a time;
Ray's stop waits the studio's grace period, not Ray's 3 s, before SIGKILL.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from mimickit.learning.run_folder import RunFolder, is_event_row
from tests.studio.conftest import REAL_TRAINER, StudioProcess, wait_for, write_arg_file
from tests.studio.ray_head import free_port, local_ray_head

ray = pytest.importorskip("ray", reason="the Ray tests need the ray extra: pip install -e '.[ray]'")
pytestmark = pytest.mark.integration

DEMO_ARGS = "args/deepmimic_humanoid_demo_ppo_args.txt"
PER_ITER = 4 * 32  # samples per iteration with --num_envs 4
RAY_CPUS = 2
WAIT_S = 300.0


@pytest.fixture(scope="session")
def ray_head() -> Iterator[str]:
    """One Ray head (2 CPUs) for this file's tests; its dashboard URL."""
    with local_ray_head(RAY_CPUS) as url:
        yield url


def ray_studio(runs_dir: Path, ray_url: str, trainer: str | None = None) -> StudioProcess:
    extra = ("--executor", "ray", "--ray-address", ray_url, "--clip", "none")
    return StudioProcess(runs_dir, None, *extra, **({"trainer": trainer} if trainer else {}))


def run_of(studio: StudioProcess, run_id: int) -> dict:
    return studio.get(f"/api/runs/{run_id}").json()


def wait_status(studio: StudioProcess, run_id: int, *statuses: str, timeout: float = WAIT_S) -> dict:
    return wait_for(
        lambda: (r := run_of(studio, run_id))["status"] in statuses and r, timeout, f"run {run_id} to be {statuses}"
    )


def training_rows(studio: StudioProcess, run_id: int) -> list[dict]:
    rows = studio.get(f"/api/runs/{run_id}/metrics", params={"follow": "false"}).json()
    return [r for r in rows if not is_event_row(r)]


def test_stop_waits_the_studio_grace_period_not_rays_default(ray_head: str, tmp_path: Path) -> None:
    """A job that needs 5 s after SIGTERM (a checkpoint) finishes it: Ray alone would SIGKILL after 3 s."""
    from studio.runs.executors import JobState, Launch
    from studio.runs.executors.ray import RayExecutor

    executor = RayExecutor(ray_head, stop_timeout_s=30)
    script = "import signal,time,pathlib\n"
    script += "def term(*_):\n time.sleep(5); pathlib.Path('saved').write_text('ok'); raise SystemExit(0)\n"
    script += "signal.signal(signal.SIGTERM, term)\npathlib.Path('up').touch()\ntime.sleep(120)\n"
    launch = Launch([sys.executable, "-c", script], tmp_path, tmp_path / "console.log", num_cpus=0.5)
    job_id = executor.submit(launch)
    wait_for(lambda: (tmp_path / "up").exists(), WAIT_S, "the job to start in its work dir")
    executor.stop(job_id)
    job = wait_for(lambda: (j := executor.status(job_id)).state == JobState.ENDED and j, 60.0, "the job to end")
    assert (tmp_path / "saved").read_text() == "ok", executor.logs(job_id)
    assert job.ended_at >= job.started_at and executor.status("raysubmit_unknown") is None


def test_launch_stream_stop_resume_as_ray_jobs(ray_head: str, tmp_path: Path) -> None:
    studio = ray_studio(tmp_path, ray_head, REAL_TRAINER)
    try:
        body = {"arg_file": DEMO_ARGS, "num_envs": 4, "max_samples": 1000 * PER_ITER, "rand_seed": 3, "num_cpus": 1}
        r = studio.post("/api/runs", body)
        assert r.status_code == 201, r.text
        run = r.json()
        assert run["executor"] == "ray" and run["status"] == "queued"
        running = wait_status(studio, run["id"], "running")
        first_job = running["job_id"]
        assert first_job.startswith("raysubmit_") and running["started_at"]
        wait_for(lambda: training_rows(studio, run["id"]), WAIT_S, "a metrics row")
        log = studio.get(f"/api/runs/{run['id']}/log").json()["lines"]  # Ray's log of the job, while it runs
        assert any(line.startswith(f"Running entrypoint for job {first_job}") for line in log), log
        assert studio.post(f"/api/runs/{run['id']}/stop").json()["status"] == "stopping"
        stopped = wait_status(studio, run["id"], "stopped", "failed", "interrupted")
        assert stopped["status"] == "stopped", stopped
        assert stopped["checkpoint"] == str(RunFolder(stopped["out_dir"]).model_file)
        assert "Running entrypoint for job" in (Path(stopped["out_dir"]) / "console.log").read_text()
        done = stopped["summary"]["samples"]
        r = studio.post(f"/api/runs/{run['id']}/resume", {"max_samples": done + 2 * PER_ITER})
        assert r.status_code == 200, r.text
        finished = wait_status(studio, run["id"], "finished", "failed", "stopped")
        assert finished["status"] == "finished", finished
        assert finished["job_id"] != first_job and finished["attempts"] == 2
        assert finished["summary"]["samples"] == done + 2 * PER_ITER and finished["summary"]["resumes"] == 1
    finally:
        studio.stop()


def test_a_restarted_studio_keeps_a_running_job_attached(ray_head: str, tmp_path: Path) -> None:
    arg_file = write_arg_file(tmp_path, "long", rows=600, period=0.2)
    first = ray_studio(tmp_path, ray_head)
    r = first.post("/api/runs", {"arg_file": str(arg_file), "num_cpus": 1})
    run_id = r.json()["id"]
    job_id = wait_status(first, run_id, "running")["job_id"]
    wait_for(lambda: training_rows(first, run_id), WAIT_S, "a metrics row")
    first.kill9()  # a Ray job is the cluster's: it goes on without the server that submitted it
    second = ray_studio(tmp_path, ray_head)
    try:
        again = run_of(second, run_id)
        assert (again["status"], again["job_id"]) == ("running", job_id), again
        seen = len(training_rows(second, run_id))
        wait_for(lambda: len(training_rows(second, run_id)) > seen, 60.0, "rows after the restart")
        second.post(f"/api/runs/{run_id}/stop")
        stopped = wait_status(second, run_id, "stopped", "failed", "interrupted")
        assert stopped["status"] == "stopped" and stopped["checkpoint"], stopped
    finally:
        second.stop()


def test_a_sweep_of_four_runs_runs_two_at_a_time(ray_head: str, tmp_path: Path) -> None:
    arg_file = write_arg_file(tmp_path, "sweep", rows=12, period=0.25)
    studio = ray_studio(tmp_path, ray_head)
    try:
        r = studio.post("/api/sweeps", {"arg_file": str(arg_file), "values": {"rand_seeds": [1]}})
        assert r.status_code == 400 and "did you mean 'rand_seed'" in r.json()["detail"]
        cli = [sys.executable, "-m", "studio.cli", "sweep", str(arg_file), "--values", "rand_seed=0,1,2,3"]
        cli += ["--num-cpus", "1", "--name", "seeds", "--url", studio.url]
        out = subprocess.run(cli, capture_output=True, text=True, timeout=120)
        assert out.returncode == 0 and "4 runs queued" in out.stdout, out.stderr
        sweep = studio.get("/api/sweeps").json()[-1]
        assert sweep["name"] == "seeds" and len(sweep["run_ids"]) == 4
        runs = [wait_status(studio, i, "finished", "failed", timeout=300.0) for i in sweep["run_ids"]]
        assert [r["status"] for r in runs] == ["finished"] * 4, [r["reason"] for r in runs]
        assert sorted(r["summary"]["seed"] for r in runs) == [0, 1, 2, 3]
        assert {r["sweep_id"] for r in runs} == {sweep["id"]} and {r["config"]["num_cpus"] for r in runs} == {1}
        spans = [(r["started_at"], r["ended_at"]) for r in runs]
        at_once = max(sum(s <= t < e for s, e in spans) for t, _ in spans)
        assert at_once == RAY_CPUS, spans  # never a third (Ray queued it), and two did overlap
    finally:
        studio.stop()


def test_serve_with_no_ray_dashboard_there_is_one_line(tmp_path: Path) -> None:
    argv = [sys.executable, "-m", "studio.cli", "serve", "--port", "0", "--clip", "none", "--runs-dir", str(tmp_path)]
    argv += ["--executor", "ray", "--ray-address", f"http://127.0.0.1:{free_port()}"]
    out = subprocess.run(argv, capture_output=True, text=True, timeout=120)
    assert out.returncode == 2 and out.stdout == "", out
    assert out.stderr.startswith("error: --ray-address http://127.0.0.1:") and "no Ray dashboard answers" in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1, out.stderr
