"""Hostile sweeps, launches and the run queue against a real `mimickit-studio serve` (issue 34): a sweep
value naming a file outside the folders, argument injection through a value, a sweep too large to
build, a flooded queue and its bulk stop, ids past SQLite's integers, and numbers the trainer refuses.
Each bad request is one line (4xx) and queues no run; runs use the stand-in trainer.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.hostile.test_http import one_line
from tests.studio.conftest import StudioProcess, wait_for, write_arg_file

pytestmark = pytest.mark.integration

SECRET = "root:s3cr3t-hash-of-the-outside-file:20228:0:99999:7:::"
HUGE_ID = 2**63


@pytest.fixture(scope="module")
def srv(tmp_path_factory: pytest.TempPathFactory) -> Iterator[StudioProcess]:
    runs_dir = tmp_path_factory.mktemp("sweep_runs")
    write_arg_file(runs_dir, "short", rows=2, period=0.05)
    server = StudioProcess(runs_dir)
    yield server
    server.stop()


@pytest.fixture(scope="module")
def outside(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A file outside the data and runs folders, as /etc/shadow is."""
    path = tmp_path_factory.mktemp("outside") / "shadow.yaml"
    path.write_text(f"{SECRET}\n")
    return path


def arg(server: StudioProcess) -> str:
    return str(server.runs_dir / "args" / "short.txt")


def run_ids(server: StudioProcess) -> list[int]:
    return [r["id"] for r in server.get("/api/runs").json()]


def refused(server: StudioProcess, path: str, body: object, status: int, says: str) -> str:
    """POST `body`: `status` with one line holding `says`, and no run queued."""
    before = run_ids(server)
    r = server.post(path, body)
    assert r.status_code == status, r.text
    detail = one_line(r)
    assert says in detail, detail
    assert run_ids(server) == before
    return detail


@pytest.mark.parametrize("key", ["engine_config", "env_config", "agent_config"])
def test_a_sweep_config_value_outside_the_folders_is_refused_and_leaks_nothing(
    srv: StudioProcess, outside: Path, key: str
) -> None:
    """Item 1: the config yamls of a sweep's values are confined as every path of a request."""
    cases = [
        (str(outside), 403, "outside"),
        ("/etc/shadow", 403, "outside"),
        (f"data/../../{outside.name}", 403, "'..' is not allowed"),
        ("data/envs/no.yaml", 404, "not found"),
    ]
    for path, status, says in cases:
        body = {"arg_file": arg(srv), "values": {key: [path]}}
        detail = refused(srv, "/api/sweeps", body, status, says)
        assert SECRET not in detail and "s3cr3t" not in detail
    everything = srv.get("/api/runs").text + srv.get("/api/sweeps").text
    assert "s3cr3t" not in everything


def test_a_sweep_config_value_inside_the_folders_reaches_the_trainer_resolved(srv: StudioProcess) -> None:
    r = srv.post(
        "/api/sweeps", {"arg_file": arg(srv), "values": {"env_config": ["data/envs/deepmimic_humanoid_env.yaml"]}}
    )
    assert r.status_code == 201, r.text
    (run,) = r.json()["runs"]
    done = wait_for(lambda: (x := srv.get(f"/api/runs/{run['id']}").json())["command"] and x, what="its command")
    value = done["command"][done["command"].index("--env_config") + 1]
    assert Path(value).is_absolute() and value.endswith("data/envs/deepmimic_humanoid_env.yaml")


@pytest.mark.parametrize(
    ("key", "value", "says"),
    [
        ("devices", "cpu --model_file /elsewhere/model.pt", "unknown device 'cpu --model_file /elsewhere/model.pt'"),
        ("devices", "cpu --data_dir /", "unknown device"),
        ("devices", ["--model_file", "/elsewhere/model.pt"], "'--model_file' is not a value"),
        ("logger", "--data_dir", "'--data_dir' is not a value"),
        ("logger", "# comment", "is not a value"),
        ("logger", "txt\n--data_dir /", "is not a value"),
        ("test_episodes", "5 --model_file /x", "expected an integer"),
        ("visualize", ["true", "true"], "--visualize takes one value, got 2"),
        ("save_int_models", True, "values: save_int_models is one value for all of a sweep's runs"),
        ("devices", ["cuda:99"], "--devices cuda:99"),
        ("devices", [], "values.devices: an empty list is no value"),
    ],
)
def test_a_sweep_value_is_one_argv_item_checked_as_the_trainer_checks_it(
    srv: StudioProcess, key: str, value: object, says: str
) -> None:
    """Item 2: a value is never split into trainer arguments; the trainer's own checks refuse it before
    any run is queued."""
    refused(srv, "/api/sweeps", {"arg_file": arg(srv), "values": {key: [value]}}, 400, says)


def test_several_devices_are_a_list_each_one_argv_item(srv: StudioProcess) -> None:
    r = srv.post("/api/sweeps", {"arg_file": arg(srv), "values": {"devices": [["cpu", "cpu"]]}, "name": "two"})
    assert r.status_code == 201, r.text
    (run,) = r.json()["runs"]
    assert run["name"] == "two devices=cpu,cpu" and run["config"]["args"] == {"devices": ["cpu", "cpu"]}
    done = wait_for(lambda: (x := srv.get(f"/api/runs/{run['id']}").json())["command"] and x, what="its command")
    assert done["command"][done["command"].index("--devices") + 1 :][:2] == ["cpu", "cpu"]


def test_a_sweep_is_sized_from_its_value_counts_before_anything_is_built(srv: StudioProcess) -> None:
    """Item 3: 3 keys x 300 values (27 million runs) is one line at once, not 5 GB and a 500."""
    values = {"rand_seed": list(range(300)), "num_envs": list(range(1, 301)), "max_samples": list(range(1, 301))}
    refused(srv, "/api/sweeps", {"arg_file": arg(srv), "values": values}, 400, "the sweep makes 27000000 runs")


@pytest.mark.parametrize(
    ("body", "says"),
    [
        ('{"arg_file": "A", "max_hours": Infinity}', "max_hours: Input should be a finite number"),
        ('{"arg_file": "A", "max_hours": NaN}', "max_hours: Input should be a finite number"),
        ('{"arg_file": "A", "max_hours": 1e400}', "max_hours: Input should be a finite number"),
        ('{"arg_file": "A", "rand_seed": true}', "rand_seed: Input should be a valid integer"),
        ('{"arg_file": "A", "num_envs": false}', "num_envs: Input should be a valid integer"),
        ('{"arg_file": "A", "max_samples": 64.0}', "max_samples: Input should be a valid integer"),
        ('{"arg_file": "A", "num_cpus": Infinity}', "num_cpus: Input should be a finite number"),
        ('{"arg_file": "A", "name": "a\\nb"}', "name: String should match pattern"),
    ],
)
def test_a_launch_refuses_numbers_the_trainer_would_refuse(srv: StudioProcess, body: str, says: str) -> None:
    """Item 11: JSON's Infinity/NaN, a float too large, and booleans for integers are refused, not taken as
    1 or passed on to a trainer that fails."""
    before = run_ids(srv)
    content = body.replace('"A"', json.dumps(arg(srv)))
    for path in ("/api/runs", "/api/sweeps"):
        r = srv.client.post(path, content=content, headers={"Content-Type": "application/json"})
        assert r.status_code == 422 and says in one_line(r), r.text
    assert run_ids(srv) == before


@pytest.mark.parametrize(
    ("values", "says"),
    [
        ('{"rand_seed": [true]}', "rand_seed: Input should be a valid integer"),
        ('{"max_hours": [Infinity]}', "max_hours: Input should be a finite number"),
        ('{"test_episodes": [1e400]}', "--test_episodes: expected an integer, got 'inf'"),
        ('{"master_port": [NaN]}', "--master_port: expected an integer, got 'nan'"),
    ],
)
def test_a_sweep_refuses_numbers_the_trainer_would_refuse(srv: StudioProcess, values: str, says: str) -> None:
    content = f'{{"arg_file": {json.dumps(arg(srv))}, "values": {values}}}'
    before = run_ids(srv)
    r = srv.client.post("/api/sweeps", content=content, headers={"Content-Type": "application/json"})
    assert r.status_code == 400 and says in one_line(r), r.text
    assert run_ids(srv) == before


@pytest.mark.parametrize(
    ("body", "says"),
    [
        ('{"max_samples": true}', "max_samples: Input should be a valid integer"),
        ('{"max_hours": Infinity}', "max_hours: Input should be a finite number"),
        ('{"max_hours": NaN}', "max_hours: Input should be a finite number"),
    ],
)
def test_a_resume_refuses_numbers_the_trainer_would_refuse(srv: StudioProcess, body: str, says: str) -> None:
    r = srv.client.post("/api/runs/1/resume", content=body, headers={"Content-Type": "application/json"})
    assert r.status_code == 422 and says in one_line(r), r.text


def test_errors_quote_at_most_a_bounded_part_of_the_input(srv: StudioProcess) -> None:
    """Item 11: a 10,000-character key or path is cut in the line that names it."""
    long = "k" * 10_000
    for body, status in (
        ({"arg_file": arg(srv), "values": {long: [1]}}, 400),
        ({"arg_file": arg(srv), long: 1}, 422),
        ({"arg_file": arg(srv), "values": {"devices": ["x" * 10_000]}}, 400),
        ({"arg_file": arg(srv), "values": {"env_config": ["/" + "e" * 10_000]}}, 400),
        ({"arg_file": "/" + "a" * 10_000}, 400),
        ({"arg_file": "args/" + "a" * 10_000}, 404),
        ({"arg_file": arg(srv), "motion_file": "data/" + "m" * 10_000}, 400),
    ):
        r = srv.post("/api/sweeps", body)
        assert r.status_code in (status, 400, 403, 404), r.text
        assert len(one_line(r)) < 300, r.text


@pytest.mark.parametrize(
    ("method", "path", "body"),
    [
        ("GET", f"/api/runs/{HUGE_ID}", None),
        ("POST", f"/api/runs/{HUGE_ID}/resume", {}),
        ("POST", f"/api/runs/{HUGE_ID}/stop", None),
        ("POST", f"/api/runs/{HUGE_ID}/again", {}),
        ("DELETE", f"/api/runs/{HUGE_ID}", None),
        ("GET", f"/api/runs/{HUGE_ID}/log", None),
        ("GET", f"/api/runs/{HUGE_ID}/metrics?follow=false", None),
        ("GET", f"/api/compare?runs=1,{HUGE_ID}", None),
        ("POST", "/api/scene/load_rollout", {"run_id": HUGE_ID}),
        (
            "POST",
            "/api/scene/load_rollout",
            {"checkpoint": "data/models/deepmimic_humanoid_demo_model.pt", "b_run_id": HUGE_ID},
        ),
        ("POST", "/api/runs/stop", {"ids": [HUGE_ID]}),
    ],
)
def test_an_id_past_sqlites_integers_is_no_run(srv: StudioProcess, method: str, path: str, body: object) -> None:
    """Item 10: 2^63 was an OverflowError (HTTP 500); now it names no run."""
    r = srv.client.request(method, path, json=body)
    assert r.status_code == 404 and one_line(r).startswith("no run"), r.text


@pytest.fixture(scope="module")
def capped(tmp_path_factory: pytest.TempPathFactory) -> Iterator[StudioProcess]:
    """A server whose queue holds 3 runs; its runs last long enough to stay queued behind the first."""
    runs_dir = tmp_path_factory.mktemp("capped_runs")
    write_arg_file(runs_dir, "long", rows=400, period=0.2)
    server = StudioProcess(runs_dir, None, "--max-queued-runs", "3")
    yield server
    server.stop()


def runs_of(server: StudioProcess, ids: list[int]) -> list[dict]:
    return [server.get(f"/api/runs/{i}").json() for i in ids]


def test_the_queue_is_capped_and_a_bulk_stop_empties_it(capped: StudioProcess) -> None:
    """Item 6: past `--max-queued-runs` a launch or sweep is one 429 line and adds nothing; one request
    stops a whole sweep or a list of runs, and the queued ones never start."""
    long = str(capped.runs_dir / "args" / "long.txt")
    first = capped.post("/api/runs", {"arg_file": long}).json()
    wait_for(lambda: capped.get(f"/api/runs/{first['id']}").json()["status"] == "running", what="the first run")
    r = capped.post("/api/sweeps", {"arg_file": long, "values": {"rand_seed": [1, 2, 3]}})
    assert r.status_code == 201, r.text
    sweep = r.json()
    refused(capped, "/api/runs", {"arg_file": long}, 429, "the queue holds 3 runs and takes at most 3")
    sweeps_before = capped.get("/api/sweeps").json()
    refused(capped, "/api/sweeps", {"arg_file": long, "values": {"rand_seed": [4]}}, 429, "--max-queued-runs")
    assert capped.get("/api/sweeps").json() == sweeps_before  # no empty sweep left behind
    wait_for(lambda: capped.get(f"/api/runs/{first['id']}").json()["summary"]["seed"] is not None, what="a seed")
    refused(capped, f"/api/runs/{first['id']}/again", {}, 429, "the queue holds 3 runs")

    r = capped.post("/api/runs/stop", {"sweep_id": sweep["id"]})
    assert r.status_code == 200, r.text
    swept = [run["id"] for run in sweep["runs"]]
    assert r.json() == {"stopped": swept, "stopping": [], "ended": []}
    stopped = runs_of(capped, swept)
    assert {run["status"] for run in stopped} == {"stopped"} and all(run["command"] is None for run in stopped)

    queued = [capped.post("/api/runs", {"arg_file": long}).json()["id"] for _ in range(2)]
    r = capped.post("/api/runs/stop", {"ids": [first["id"], *queued, swept[0]]})
    assert r.status_code == 200, r.text
    assert r.json() == {"stopped": queued, "stopping": [first["id"]], "ended": [swept[0]]}
    wait_for(lambda: capped.get(f"/api/runs/{first['id']}").json()["status"] == "stopped", what="the first run")
    assert {run["status"] for run in runs_of(capped, queued)} == {"stopped"}
    assert all(run["attempts"] == 0 for run in runs_of(capped, queued))


@pytest.mark.parametrize(
    ("body", "status", "says"),
    [
        ({"ids": [1, 999_999]}, 404, "no run 999999"),
        ({"sweep_id": 999_999}, 404, "no sweep 999999"),
        ({}, 422, "give one of `ids`"),
        ({"ids": [1], "sweep_id": 1}, 422, "give one of `ids`"),
        ({"ids": [True]}, 422, "ids.0: Input should be a valid integer"),
        ({"ids": list(range(10_001))}, 422, "ids: List should have at most 10000 items"),
    ],
)
def test_a_bad_bulk_stop_is_one_line_and_stops_nothing(
    capped: StudioProcess, body: dict, status: int, says: str
) -> None:
    long = str(capped.runs_dir / "args" / "long.txt")
    run = capped.post("/api/runs", {"arg_file": long}).json()
    r = capped.post("/api/runs/stop", body)
    assert r.status_code == status and says in one_line(r), r.text
    assert capped.get(f"/api/runs/{run['id']}").json()["status"] in ("queued", "running")
    capped.post("/api/runs/stop", {"ids": [run["id"]]})


def test_the_sweep_command_sends_several_devices_as_a_list(srv: StudioProcess) -> None:
    """`mimickit-studio sweep --values "devices=cpu cpu"` (as docs/studio.md writes it) is one value of two
    devices, each its own trainer argument; the server itself never splits a value."""
    argv = [sys.executable, "-m", "studio.cli", "sweep", arg(srv), "--values", "devices=cpu cpu", "--url", srv.url]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    sweep = srv.get("/api/sweeps").json()[-1]
    assert sweep["spec"]["values"] == {"devices": [["cpu", "cpu"]]}
    (run_id,) = sweep["run_ids"]
    assert srv.get(f"/api/runs/{run_id}").json()["config"]["args"] == {"devices": ["cpu", "cpu"]}


def test_the_sweep_command_sends_numbers_as_numbers(srv: StudioProcess) -> None:
    """`--values rand_seed=0,1` queues two runs with the integer seeds (the studio takes no string for an
    integer field, as it takes no `true`); a clip's name stays a string."""
    argv = [sys.executable, "-m", "studio.cli", "sweep", arg(srv), "--values", "rand_seed=0,1", "--url", srv.url]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and "2 runs queued" in done.stdout, done.stderr
    sweep = srv.get("/api/sweeps").json()[-1]
    assert sweep["spec"]["values"] == {"rand_seed": [0, 1]}
    assert [srv.get(f"/api/runs/{i}").json()["config"]["rand_seed"] for i in sweep["run_ids"]] == [0, 1]
    srv.post("/api/runs/stop", {"sweep_id": sweep["id"]})


@pytest.mark.parametrize("what", ["folder", "registry"])
@pytest.mark.parametrize("path", ["/api/runs", "/api/sweeps"])
def test_a_folder_or_the_registry_is_no_arg_file(srv: StudioProcess, path: str, what: str) -> None:
    """The runs folder or its registry.sqlite as a launch's or sweep's arg file: one 400 line and no run
    (the trainer would refuse either: 'arg file not found', 'a binary file')."""
    given = str(srv.runs_dir if what == "folder" else srv.runs_dir / "registry.sqlite")
    refused(srv, path, {"arg_file": given, "values": {}} if "sweeps" in path else {"arg_file": given}, 400, "arg file")
