"""Runs through the real server: subprocess trainers (the fake one that keeps the `mimickit train`
contract; test_launch_fields.py runs the same flows with the real trainer), their end states, metrics and
checkpoints; the queue; a server killed with -9 and restarted; the API's path forms, "again with this
seed" and "continue with a budget"."""

from __future__ import annotations

import json
import os
from pathlib import Path

import httpx
import pytest

from mimickit.util.paths import PROJECT_ROOT
from tests.conftest import DEMO_CLIP
from tests.studio.conftest import StudioProcess, wait_for, write_arg_file

pytestmark = pytest.mark.integration


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


def test_run_goes_running_then_finished(studio: StudioProcess) -> None:
    run = launch(studio, "short", name="first run", num_envs=8)
    assert run["status"] in ("queued", "running")
    running = wait_status(studio, run["id"], "running", "finished")
    argv = running["command"]  # recorded with the run, as the trainer was started
    assert argv[argv.index("--arg_file") + 1] == str(studio.runs_dir / "args" / "short.txt")
    assert argv[argv.index("--out_dir") + 1] == running["out_dir"]
    assert argv[argv.index("--num_envs") + 1] == "8"
    done = wait_status(studio, run["id"], "finished")
    assert done["exit_code"] == 0 and done["ended_at"] >= done["started_at"] and done["reason"] is None
    rows = metrics(studio, run["id"])
    assert [r["iteration"] for r in rows] == list(range(1, 9))
    assert {"train_return", "test_return", "reward_terms.pose", "actor_loss"} <= set(rows[0])
    assert done["checkpoint"] and checkpoint(done)["iteration"] == 8
    assert "fake trainer" in (Path(done["out_dir"]) / "console.log").read_text()
    assert Path(done["out_dir"]).parent == studio.runs_dir and "first-run" in done["out_dir"]
    summary = done["summary"]  # from the run folder, not from what was asked
    assert summary["num_envs"] == 8 and summary["samples"] == 8 * 8 * 32 and summary["end_state"] == "finished"
    assert summary["seed"] is not None and summary["test_return"] == 72.0 and summary["elapsed_s"] > 0


def test_metrics_rows_from_an_index(studio: StudioProcess) -> None:
    run = launch(studio, "short")
    wait_status(studio, run["id"], "finished")
    assert [r["iteration"] for r in metrics(studio, run["id"])] == list(range(1, 9))
    rows = studio.get(f"/api/runs/{run['id']}/metrics", params={"start": 6}).json()
    assert [r["iteration"] for r in rows] == [7, 8]
    # The live rows are GET /api/stream's `metrics` events (test_stream.py); the older per-run event
    # stream is retired, and asking for it says where the rows are.
    r = studio.get(f"/api/runs/{run['id']}/metrics", params={"follow": "true"})
    assert r.status_code == 410 and f"GET /api/stream?run={run['id']}" in r.json()["detail"], r.text


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
    wait_status(studio, second["id"], "running", "finished")
    wait_status(studio, second["id"], "finished")
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
    assert failed["exit_code"] == 3 and failed["reason"] == "fake failure with exit code 3"
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
        rows = metrics(server, run_id)
        marker = rows[done_before]
        assert (marker["event"], marker["iteration"], marker["samples"]) == ("resume", done_before, done_before * 128)
        its = [row["iteration"] for row in rows if "event" not in row]
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


def launch_and_cancel(studio: StudioProcess, **body: object) -> httpx.Response:
    """POST /api/runs; a run it queues is stopped before it starts (the path is what is tested)."""
    r = studio.post("/api/runs", body)
    if r.status_code == 201:
        studio.post(f"/api/runs/{r.json()['id']}/stop")
    return r


def test_api_takes_the_cli_path_forms(studio: StudioProcess) -> None:
    demo = PROJECT_ROOT / "args" / "deepmimic_humanoid_demo_ppo_args.txt"
    for form in ("args/deepmimic_humanoid_demo_ppo_args.txt", str(demo), "deepmimic_humanoid_demo_ppo_args.txt"):
        r = launch_and_cancel(studio, arg_file=form)
        assert r.status_code == 201, (form, r.text)
        assert r.json()["config"]["arg_file"] == str(demo)
    saved = launch_and_cancel(studio, arg_file="args/short.txt")  # the runs folder's args/ too
    assert saved.status_code == 201
    assert saved.json()["config"]["arg_file"] == str(studio.runs_dir / "args" / "short.txt")
    clip = launch_and_cancel(studio, arg_file="args/short.txt", motion_file="data/motions/humanoid_demo_squat.pkl")
    assert clip.status_code == 201 and clip.json()["config"]["motion_file"] == str(DEMO_CLIP)

    missing = studio.post("/api/runs", {"arg_file": "args/no_such_args.txt"})
    assert missing.status_code == 404 and missing.json()["detail"] == "arg file not found: args/no_such_args.txt"
    for outside in ("/etc/passwd", "args/../../etc/passwd", "../pyproject.toml"):
        assert studio.post("/api/runs", {"arg_file": outside}).status_code == 403, outside
    xml = "data/assets/humanoid/humanoid.xml"
    not_a_clip = studio.post("/api/runs", {"arg_file": "args/short.txt", "motion_file": xml})
    assert not_a_clip.status_code == 400 and "humanoid.xml" in not_a_clip.json()["detail"]


def test_unknown_launch_keys_are_refused_by_name(studio: StudioProcess) -> None:
    r = studio.post("/api/runs", {"arg_file": "args/short.txt", "num_env": 8})
    assert r.status_code == 422 and r.json() == {"detail": "unknown key 'num_env'; did you mean 'num_envs'?"}
    r = studio.post(f"/api/runs/{launch(studio, 'short')['id']}/resume", {"budget": 10})
    assert r.status_code == 422 and r.json()["detail"] == "unknown key 'budget'; known keys: max_samples, max_hours"
    r = studio.post("/api/runs", {"arg_file": "args/short.txt", "rand_seed": -1})
    assert r.status_code == 422 and r.json()["detail"] == "rand_seed: Input should be greater than or equal to 0"
    r = studio.post("/api/runs", {"arg_file": "args/short.txt", "num_envs": 65_537})
    assert r.status_code == 422 and r.json()["detail"] == "num_envs: Input should be less than or equal to 65536"
    r = studio.post("/api/runs", {"num_envs": "many"})
    assert r.status_code == 422 and r.json()["detail"].startswith("arg_file: Field required (and 1 more)")


def test_again_with_the_seed_of_a_run(studio: StudioProcess) -> None:
    seeded = wait_status(studio, launch(studio, "short", rand_seed=123, num_envs=2)["id"], "finished")
    assert seeded["summary"]["seed"] == 123
    unseeded = wait_status(studio, launch(studio, "short")["id"], "finished")
    picked = unseeded["summary"]["seed"]  # the trainer picked one and recorded it
    assert isinstance(picked, int)
    for run, seed in ((seeded, 123), (unseeded, picked)):
        r = studio.post(f"/api/runs/{run['id']}/again", {})
        assert r.status_code == 201, r.text
        again = wait_status(studio, r.json()["id"], "finished")
        assert again["config"] == {**run["config"], "rand_seed": seed} and again["id"] != run["id"]
        argv = again["command"]
        assert argv[argv.index("--rand_seed") + 1] == str(seed) and again["summary"]["seed"] == seed
        assert again["summary"]["num_envs"] == run["summary"]["num_envs"]
    never_started = launch(studio, "long")
    studio.post(f"/api/runs/{never_started['id']}/stop")
    r = studio.post(f"/api/runs/{never_started['id']}/again", {})
    assert r.status_code == 409 and "recorded no seed" in r.json()["detail"]
    assert studio.post("/api/runs/999999/again", {}).status_code == 404


def test_continue_a_finished_run_with_a_larger_budget(studio: StudioProcess) -> None:
    per_row = 4 * 32  # the fake trainer's default 4 envs
    run = wait_status(studio, launch(studio, "long", max_samples=3 * per_row)["id"], "finished")
    assert run["summary"]["samples"] == 3 * per_row and run["summary"]["max_samples"] == 3 * per_row
    r = studio.post(f"/api/runs/{run['id']}/resume", {})
    assert r.status_code == 409 and "reached its budget (384 samples, " in r.json()["detail"]
    r = studio.post(f"/api/runs/{run['id']}/resume", {"max_samples": 3 * per_row})
    assert r.status_code == 409 and "not more than the 384 samples" in r.json()["detail"]
    r = studio.post(f"/api/runs/{run['id']}/resume", {"max_samples": 5 * per_row})
    assert r.status_code == 200, r.text
    done = wait_status(studio, run["id"], "finished")
    argv = done["command"]
    assert argv[argv.index("--max_samples") + 1] == str(5 * per_row) and "--model_file" in argv
    rows = metrics(studio, run["id"])
    assert [r.get("event") for r in rows] == [None] * 3 + ["resume"] + [None] * 2
    assert rows[3]["samples"] == 3 * per_row and rows[-1]["samples"] == 5 * per_row
    assert done["summary"]["resumes"] == 1 and done["summary"]["max_samples"] == 5 * per_row


def test_a_typo_in_the_arg_file_fails_the_run(studio: StudioProcess) -> None:
    """The fake trainer runs the real trainer's argument checks: a typo ends the run failed, naming it
    (test_launch_fields.py has the same run with the real trainer)."""
    path = write_arg_file(studio.runs_dir, "typo", rows=2, period=0.05)
    path.write_text(path.read_text() + "--num_env 8\n")
    failed = wait_status(studio, launch(studio, "typo")["id"], "failed")
    assert failed["exit_code"] == 2 and not (Path(failed["out_dir"]) / "metrics.jsonl").exists()
    assert "unknown argument --num_env" in failed["reason"] and "(did you mean --num_envs?)" in failed["reason"]


def test_a_sweep_queues_one_run_per_combination_in_one_group(studio: StudioProcess) -> None:
    arg = str(studio.runs_dir / "args" / "short.txt")
    values = {"rand_seed": [5, 6], "num_envs": [2], "test_episodes": [3]}
    body = {"arg_file": arg, "values": values, "name": "two seeds", "save_int_models": True}  # a launch field: shared
    r = studio.post("/api/sweeps", body)
    assert r.status_code == 201, r.text
    sweep = r.json()
    names = [run["name"] for run in sweep["runs"]]
    assert names == [f"two seeds rand_seed={s} num_envs=2 test_episodes=3" for s in (5, 6)]
    runs = [wait_status(studio, run["id"], "finished", timeout=120.0) for run in sweep["runs"]]
    assert [(r["summary"]["seed"], r["summary"]["num_envs"]) for r in runs] == [(5, 2), (6, 2)]
    assert all(r["command"][-2:] == ["--test_episodes", "3"] for r in runs)  # any --key reaches the trainer
    assert all(r["config"]["save_int_models"] is True for r in runs)
    assert all(r["command"][r["command"].index("--save_int_models") + 1] == "true" for r in runs)
    assert {r["sweep_id"] for r in runs} == {sweep["id"]} and {r["executor"] for r in runs} == {"local"}
    listed = studio.get(f"/api/sweeps/{sweep['id']}").json()
    assert listed["run_ids"] == [r["id"] for r in runs] and listed["spec"]["values"] == values


@pytest.mark.parametrize(
    ("values", "says"),
    [
        ({"out_dir": ["/tmp/x"]}, "values: unknown argument 'out_dir'"),
        ({"num_env": [2]}, "did you mean 'num_envs'?"),
        ({"rand_seed": []}, "values.rand_seed: give at least one value"),
        ({"num_envs": [0]}, "values: num_envs: Input should be greater than 0"),
        ({"rand_seed": list(range(17)), "num_envs": list(range(1, 17))}, "the sweep makes 272 runs; at most 256"),
    ],
)
def test_a_bad_sweep_is_one_line_and_queues_nothing(studio: StudioProcess, values: dict, says: str) -> None:
    before = len(studio.get("/api/runs").json())
    r = studio.post("/api/sweeps", {"arg_file": str(studio.runs_dir / "args" / "short.txt"), "values": values})
    assert r.status_code == 400 and says in r.json()["detail"], r.text
    assert len(studio.get("/api/runs").json()) == before
