"""Runs through the real server: subprocess trainers (the fake one that keeps the `mimickit train`
contract), their statuses, metrics and checkpoints; the queue; a server killed with -9 and restarted."""

from __future__ import annotations

import json
import os
from pathlib import Path

from tests.studio.conftest import StudioProcess, wait_for, write_arg_file


def launch(studio: StudioProcess, arg: str, **overrides: object) -> dict:
    r = studio.post("/api/runs", {"arg_file": str(studio.runs_dir / "args" / f"{arg}.txt"), **overrides})
    assert r.status_code == 201, r.text
    return r.json()


def run_of(studio: StudioProcess, run_id: int) -> dict:
    return studio.get(f"/api/runs/{run_id}").json()


def wait_status(studio: StudioProcess, run_id: int, *statuses: str, timeout: float = 20.0) -> dict:
    return wait_for(
        lambda: (r := run_of(studio, run_id))["status"] in statuses and r,
        timeout,
        f"run {run_id} to become {'/'.join(statuses)}",
    )


def metrics(studio: StudioProcess, run_id: int) -> list[dict]:
    return studio.get(f"/api/runs/{run_id}/metrics", params={"follow": "false"}).json()


def checkpoint(run: dict) -> dict:
    return json.loads((Path(run["out_dir"]) / "model.pt").read_text())


def test_run_goes_running_then_succeeded(studio: StudioProcess) -> None:
    run = launch(studio, "short", name="first run", num_envs=8)
    assert run["status"] in ("queued", "running")
    running = wait_status(studio, run["id"], "running", "succeeded")
    argv = running["command"]  # recorded with the run, as the trainer was started
    assert argv[argv.index("--arg_file") + 1] == str(studio.runs_dir / "args" / "short.txt")
    assert argv[argv.index("--out_dir") + 1] == running["out_dir"]
    assert argv[argv.index("--num_envs") + 1] == "8"
    done = wait_status(studio, run["id"], "succeeded")
    assert done["exit_code"] == 0 and done["ended_at"] >= done["started_at"]
    rows = metrics(studio, run["id"])
    assert [r["iteration"] for r in rows] == list(range(1, 9))
    assert {"train_return", "test_return", "reward_terms.pose", "actor_loss"} <= set(rows[0])
    assert done["checkpoint"] and checkpoint(done)["iteration"] == 8
    assert "fake trainer" in (Path(done["out_dir"]) / "console.log").read_text()
    assert Path(done["out_dir"]).parent == studio.runs_dir and "first-run" in done["out_dir"]


def test_metrics_stream_follows_the_file(studio: StudioProcess) -> None:
    run = launch(studio, "short")
    events, ended = [], None
    with studio.client.stream("GET", f"/api/runs/{run['id']}/metrics", timeout=30) as r:
        assert r.headers["content-type"].startswith("text/event-stream")
        event = None
        for line in r.iter_lines():
            if line.startswith("event: "):
                event = line[7:]
            elif line.startswith("data: "):
                if event == "end":
                    ended = json.loads(line[6:])
                    break
                events.append(json.loads(line[6:]))
    assert [e["iteration"] for e in events] == list(range(1, 9))
    assert ended == {"status": "succeeded"}
    # A reconnecting client sends Last-Event-ID (the row index) and gets only what it missed.
    with studio.client.stream("GET", f"/api/runs/{run['id']}/metrics", headers={"Last-Event-ID": "5"}, timeout=30) as r:
        rows = [json.loads(line[6:]) for line in r.iter_lines() if line.startswith('data: {"iter')]
    assert [e["iteration"] for e in rows] == [7, 8]


def test_stop_a_run_keeps_its_checkpoint(studio: StudioProcess) -> None:
    run = launch(studio, "long")
    wait_for(lambda: len(metrics(studio, run["id"])) >= 2, what="two metrics rows")
    r = studio.post(f"/api/runs/{run['id']}/stop")
    assert r.status_code == 200 and r.json()["status"] in ("stopping", "stopped")
    stopped = wait_status(studio, run["id"], "stopped")
    assert stopped["exit_code"] == 0 and stopped["checkpoint"]
    assert checkpoint(stopped)["iteration"] >= 2
    assert studio.post(f"/api/runs/{run['id']}/stop").status_code == 409  # not running any more


def test_queue_runs_one_at_a_time(studio: StudioProcess) -> None:
    first = launch(studio, "long")
    second = launch(studio, "short")
    wait_status(studio, first["id"], "running")
    assert run_of(studio, second["id"])["status"] == "queued"
    studio.post(f"/api/runs/{first['id']}/stop")
    wait_status(studio, first["id"], "stopped")
    wait_status(studio, second["id"], "running", "succeeded")
    wait_status(studio, second["id"], "succeeded")
    # A queued run that is stopped never starts.
    third, fourth = launch(studio, "long"), launch(studio, "short")
    wait_status(studio, third["id"], "running")
    assert studio.post(f"/api/runs/{fourth['id']}/stop").json()["status"] == "stopped"
    studio.post(f"/api/runs/{third['id']}/stop")
    wait_status(studio, third["id"], "stopped")
    assert run_of(studio, fourth["id"])["started_at"] is None


def test_failed_run_and_delete(studio: StudioProcess) -> None:
    write_arg_file(studio.runs_dir, "fails", rows=2, period=0.05, exit_code=3)
    run = launch(studio, "fails")
    failed = wait_status(studio, run["id"], "failed")
    assert failed["exit_code"] == 3
    out_dir = Path(failed["out_dir"])
    assert out_dir.is_dir()
    assert studio.client.delete(f"/api/runs/{run['id']}").status_code == 204
    assert not out_dir.exists()
    assert studio.get(f"/api/runs/{run['id']}").status_code == 404
    running = launch(studio, "long")
    wait_status(studio, running["id"], "running")
    assert studio.client.delete(f"/api/runs/{running['id']}").status_code == 409  # stop it first
    studio.post(f"/api/runs/{running['id']}/stop")
    wait_status(studio, running["id"], "stopped")


def test_server_killed_during_a_run(tmp_path: Path) -> None:
    """kill -9 the server: the trainer checkpoints and exits with it; the next server finds the
    registry intact, marks the run interrupted, and resumes it from the checkpoint."""
    runs_dir = tmp_path / "runs"
    write_arg_file(runs_dir, "long", rows=30, period=0.2)
    server = StudioProcess(runs_dir)
    try:
        r = server.post("/api/runs", {"arg_file": str(runs_dir / "args" / "long.txt"), "name": "survivor"})
        run_id = r.json()["id"]
        wait_for(lambda: len(metrics(server, run_id)) >= 3, what="three metrics rows")
        pid = run_of(server, run_id)["pid"]
    finally:
        server.kill9()
    wait_for(lambda: not _alive(pid), 10, "the trainer to exit after the server died")

    server = StudioProcess(runs_dir)
    try:
        run = run_of(server, run_id)
        assert run["status"] == "interrupted" and run["name"] == "survivor" and run["checkpoint"]
        done_before = checkpoint(run)["iteration"]
        assert done_before >= 3
        resumed = server.post(f"/api/runs/{run_id}/resume").json()
        assert resumed["status"] in ("queued", "running")
        running = wait_status(server, run_id, "running")
        assert running["command"][-2:] == ["--model_file", str(Path(run["out_dir"]) / "model.pt")]
        assert running["attempts"] == 2 and running["out_dir"] == run["out_dir"]
        wait_for(lambda: len(metrics(server, run_id)) > done_before + 1, what="rows after the resume")
        its = [row["iteration"] for row in metrics(server, run_id)]
        assert its[:done_before] == list(range(1, done_before + 1)) and its[done_before] == done_before + 1
        server.post(f"/api/runs/{run_id}/stop")
        wait_status(server, run_id, "stopped")
    finally:
        server.stop()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    stat = Path(f"/proc/{pid}/stat")
    return stat.exists() and stat.read_text().split(") ", 1)[1][0] != "Z"
