"""`GET /api/compare`: two runs' settings side by side (args.json, the configs as trained, the launch
form's values), the keys on which they differ, and where a run diverged (its state.json)."""

from __future__ import annotations

import pytest

from mimickit.learning.run_folder import EndState, RunFolder
from tests.studio.conftest import StudioProcess, wait_for

pytestmark = pytest.mark.integration


def finished_run(studio: StudioProcess, **overrides: object) -> dict:
    run = studio.post("/api/runs", {"arg_file": "args/short.txt", **overrides}).json()
    return wait_for(
        lambda: (r := studio.get(f"/api/runs/{run['id']}").json())["status"] == "finished" and r,
        what=f"run {run['id']} to finish",
    )


def test_compare_two_runs_lists_what_differs(studio: StudioProcess) -> None:
    a = finished_run(studio, rand_seed=1, num_envs=2)
    b = finished_run(studio, rand_seed=2, num_envs=2)
    r = studio.get("/api/compare", params={"runs": f"{a['id']},{b['id']}"})
    assert r.status_code == 200, r.text
    body = r.json()
    assert [x["id"] for x in body["runs"]] == [a["id"], b["id"]]
    diff = {d["key"]: d["values"] for d in body["diff"]}
    assert diff["seed"] == [1, 2]
    assert diff["launch.rand_seed"] == [1, 2]
    assert "launch.num_envs" not in diff  # the same in both: not a difference
    assert not any(k.endswith("out_dir") or k.startswith("start_time") for k in diff), sorted(diff)
    assert all(x["diverged"] is None for x in body["runs"])


def test_compare_says_where_a_run_diverged(studio: StudioProcess) -> None:
    run = finished_run(studio)
    RunFolder(run["out_dir"]).write_state(EndState.DIVERGED, "diverged at iteration 4: nan", iteration=4, samples=64)
    body = studio.get("/api/compare", params={"runs": str(run["id"])}).json()
    assert body["runs"][0]["diverged"] == {"iteration": 4, "samples": 64, "reason": "diverged at iteration 4: nan"}
    assert body["diff"] == []  # one run: nothing to differ from


@pytest.mark.parametrize(("runs", "status", "words"), [("3,x", 422, "run ids"), ("999999", 404, "999999")])
def test_compare_refuses_bad_ids_in_one_line(studio: StudioProcess, runs: str, status: int, words: str) -> None:
    r = studio.get("/api/compare", params={"runs": runs})
    assert r.status_code == status, r.text
    assert words in r.json()["detail"]
