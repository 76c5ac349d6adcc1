"""A run's tags and notes (`PATCH /api/runs/{id}`, kept in the SQLite registry across a server restart,
carried by the run list and the stream; strict, one-line refusals), a registry of an earlier studio
opening with them, and a run's metrics as CSV (`GET /api/runs/{id}/metrics.csv`, `GET
/api/compare/metrics.csv`): the same rows as metrics.jsonl, with the fake trainer and the real one."""

from __future__ import annotations

import csv
import io
import json
import math
import sqlite3
from pathlib import Path
from typing import Any

import pytest

from mimickit.util.paths import PROJECT_ROOT
from studio.runs.registry import Registry
from tests.studio.conftest import REAL_TRAINER, StudioProcess, wait_for, write_arg_file

pytestmark = pytest.mark.integration


def launch(server: StudioProcess, arg_file: Path | str, **body: object) -> int:
    r = server.post("/api/runs", {"arg_file": str(arg_file), **body})
    assert r.status_code == 201, r.text
    return r.json()["id"]


def ended(server: StudioProcess, run_id: int, timeout: float = 60.0) -> dict:
    return wait_for(
        lambda: (r := server.get(f"/api/runs/{run_id}").json())["status"] in ("finished", "failed") and r,
        timeout,
        f"run {run_id} to end",
    )


def jsonl_rows(run: dict) -> list[dict[str, Any]]:
    text = (Path(run["out_dir"]) / "metrics.jsonl").read_text()
    return [json.loads(line) for line in text.splitlines() if line.strip()]


def csv_rows(text: str) -> tuple[list[str], list[dict[str, str]]]:
    reader = csv.DictReader(io.StringIO(text))
    return list(reader.fieldnames or []), list(reader)


def same_value(cell: str, value: Any) -> bool:
    """A CSV cell against the metrics.jsonl value it stands for."""
    if value is None:
        return cell == ""
    if isinstance(value, bool):
        return cell == str(value).lower()
    if isinstance(value, float) and math.isnan(value):
        return cell == "nan"
    if isinstance(value, (int, float)):
        return float(cell) == value
    return cell == str(value)


def assert_csv_is_the_rows(columns: list[str], got: list[dict[str, str]], rows: list[dict[str, Any]]) -> None:
    keys = list(dict.fromkeys(k for row in rows for k in row))
    assert columns[-len(keys) :] == keys, "the columns are the union of the rows' keys, in first-seen order"
    assert len(got) == len(rows)
    for line, row in zip(got, rows, strict=True):
        for k in keys:
            assert same_value(line[k], row.get(k)), (k, line[k], row.get(k))


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Any:
    runs_dir = tmp_path_factory.mktemp("labels_runs")
    write_arg_file(runs_dir, "quick", rows=6, period=0.02)
    s = StudioProcess(runs_dir, None)
    yield s
    s.stop()


def test_tags_and_notes_round_trip_and_survive_a_restart(tmp_path: Path) -> None:
    write_arg_file(tmp_path, "quick", rows=3, period=0.02)
    server = StudioProcess(tmp_path, None)
    try:
        run_id = launch(server, tmp_path / "args" / "quick.txt", name="tagged")
        r = server.client.patch(
            f"/api/runs/{run_id}", json={"tags": ["baseline", "seed 3"], "notes": "first try\nlr 1e-4"}
        )
        assert r.status_code == 200, r.text
        assert r.json()["tags"] == ["baseline", "seed 3"] and r.json()["notes"] == "first try\nlr 1e-4"
        r = server.client.patch(f"/api/runs/{run_id}", json={"notes": "kept tags"})  # only what is given
        assert r.json()["tags"] == ["baseline", "seed 3"] and r.json()["notes"] == "kept tags"
        listed = next(x for x in server.get("/api/runs").json() if x["id"] == run_id)
        assert listed["tags"] == ["baseline", "seed 3"]
        ended(server, run_id)
    finally:
        server.stop()
    with sqlite3.connect(tmp_path / "registry.sqlite") as db:  # in the SQLite file itself
        assert db.execute("SELECT tags, notes FROM runs WHERE id = ?", (run_id,)).fetchone() == (
            '["baseline", "seed 3"]',
            "kept tags",
        )
    again = StudioProcess(tmp_path, None)
    try:
        run = again.get(f"/api/runs/{run_id}").json()
        assert run["tags"] == ["baseline", "seed 3"] and run["notes"] == "kept tags"
        with again.client.stream("GET", "/api/stream") as stream:  # the stream's runs event carries them
            data = next(line for line in stream.iter_lines() if line.startswith("data:") and '"tags"' in line)
        assert '"tags": ["baseline", "seed 3"]' in data or '"tags":["baseline","seed 3"]' in data
    finally:
        again.stop()


@pytest.mark.parametrize(
    ("body", "says"),
    [
        ({"tags": "baseline"}, "tags: "),
        ({"tags": [3]}, "tags.0: "),
        ({"tags": ["a" * 33]}, "tags: "),
        ({"tags": ["a,b"]}, "no commas"),
        ({"tags": ["bad\x07bell"]}, "control characters"),
        ({"tags": [" padded"]}, "no space at either end"),
        ({"tags": ["x", "x"]}, "each tag once"),
        ({"tags": [str(i) for i in range(17)]}, "tags: "),
        ({"notes": "n" * 2001}, "notes: "),
        ({"notes": "bidi \u202e override"}, "control characters"),
        ({"notes": 5}, "notes: "),
        ({"colour": "red"}, "unknown key 'colour'"),
        ({}, "give `tags`"),
    ],
)
def test_bad_labels_are_one_line_naming_the_key(server: StudioProcess, body: dict, says: str) -> None:
    run_id = launch(server, server.runs_dir / "args" / "quick.txt")
    r = server.client.patch(f"/api/runs/{run_id}", json=body)
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert isinstance(detail, str) and "\n" not in detail and says in detail, detail
    assert server.get(f"/api/runs/{run_id}").json()["tags"] == []


def test_labels_of_an_unknown_run_are_404(server: StudioProcess) -> None:
    r = server.client.patch("/api/runs/999999", json={"tags": ["x"]})
    assert r.status_code == 404 and r.json()["detail"] == "no run 999999"


def test_an_older_registry_opens_with_empty_tags_and_notes(tmp_path: Path) -> None:
    with sqlite3.connect(tmp_path / "registry.sqlite") as db:  # the columns an earlier studio wrote
        db.execute(
            "CREATE TABLE runs (id INTEGER PRIMARY KEY AUTOINCREMENT, name TEXT NOT NULL, config TEXT NOT NULL,"
            " status TEXT NOT NULL, pid INTEGER, created_at REAL NOT NULL, started_at REAL, ended_at REAL,"
            " out_dir TEXT NOT NULL, exit_code INTEGER, command TEXT, attempts INTEGER NOT NULL DEFAULT 0)"
        )
        db.execute(
            "INSERT INTO runs (name, config, status, created_at, out_dir) VALUES ('old', '{}', 'succeeded', 1, 'x')"
        )
    registry = Registry(tmp_path / "registry.sqlite")
    try:
        (run,) = registry.list()
        assert run.tags == [] and run.notes == "" and run.status.value == "finished"
        assert registry.update(run.id, tags=["old"], notes="from before").tags == ["old"]
    finally:
        registry.close()


def test_csv_is_the_metrics_rows(server: StudioProcess) -> None:
    ids = [launch(server, server.runs_dir / "args" / "quick.txt", num_envs=n) for n in (2, 4)]
    runs = [ended(server, i) for i in ids]
    r = server.get(f"/api/runs/{ids[0]}/metrics.csv")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
    assert f'filename="run-{ids[0]}-metrics.csv"' in r.headers["content-disposition"]
    assert_csv_is_the_rows(*csv_rows(r.text), jsonl_rows(runs[0]))
    # A resume's marker row is a row too (its own keys, the others empty).
    server.post(f"/api/runs/{ids[0]}/resume", {"max_samples": 10**6})
    resumed = ended(server, ids[0])
    rows = jsonl_rows(resumed)
    assert any("event" in row for row in rows)
    assert_csv_is_the_rows(*csv_rows(server.get(f"/api/runs/{ids[0]}/metrics.csv").text), rows)
    # Compared runs: one CSV, a run column first, each run's rows in the order asked.
    columns, got = csv_rows(server.get("/api/compare/metrics.csv", params={"runs": f"{ids[1]},{ids[0]}"}).text)
    both = jsonl_rows(runs[1]) + rows
    assert columns[0] == "run" and [g["run"] for g in got] == [str(ids[1])] * len(jsonl_rows(runs[1])) + [
        str(ids[0])
    ] * len(rows)
    assert_csv_is_the_rows(columns, got, both)


@pytest.mark.parametrize(
    ("path", "status", "says"),
    [
        ("/api/runs/999999/metrics.csv", 404, "no run 999999"),
        ("/api/runs/abc/metrics.csv", 422, "run_id"),
        ("/api/compare/metrics.csv?runs=1,x", 422, "expected run ids"),
        ("/api/compare/metrics.csv?runs=999998", 404, "no run 999998"),
    ],
)
def test_csv_of_what_is_no_run_is_one_line(server: StudioProcess, path: str, status: int, says: str) -> None:
    r = server.get(path)
    assert r.status_code == status, r.text
    detail = r.json()["detail"]
    assert isinstance(detail, str) and "\n" not in detail and says in detail, detail


@pytest.mark.slow
def test_csv_of_a_real_training_run(tmp_path: Path) -> None:
    """The same with `mimickit train`: its rows carry NaN-free floats, booleans and the test columns."""
    server = StudioProcess(tmp_path, None, trainer=REAL_TRAINER)
    try:
        arg_file = PROJECT_ROOT / "args" / "deepmimic_humanoid_demo_ppo_args.txt"
        run_id = launch(server, arg_file, name="real csv", num_envs=2, max_samples=3 * 64)
        run = ended(server, run_id, timeout=400)
        assert run["status"] == "finished", (Path(run["out_dir"]) / "console.log").read_text()[-2000:]
        rows = jsonl_rows(run)
        assert len(rows) >= 3 and any(isinstance(v, bool) for v in rows[0].values())
        assert_csv_is_the_rows(*csv_rows(server.get(f"/api/runs/{run_id}/metrics.csv").text), rows)
    finally:
        server.stop()
