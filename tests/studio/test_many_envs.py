"""A rollout of several envs through the real server: the shipped demo policy in 4 envs of one batched
env, drawn on a grid (the scene's batched figures at their cells), each env stepping from its own start,
a fall of one env (pushed hard through `POST /api/scene/rollout/push {env}`) counted for that env alone
and marked red in the 3D view, scrubbing back showing each env's figures of the frame shown, the overlay
layout, and bad `num_envs` / `layout` / A/B refused in one line."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from studio.scene.rollout import grid_cells
from tests.studio.conftest import StudioProcess, wait_for

pytestmark = pytest.mark.integration

SHIPPED = "data/models/deepmimic_humanoid_demo_model.pt"  # its arg file beside it names the configs


def _one_line(r) -> str:
    detail = r.json()["detail"]
    assert isinstance(detail, str) and "\n" not in detail, detail
    return detail


def test_four_envs_on_a_grid_step_and_count_their_falls(studio: StudioProcess) -> None:
    r = studio.post("/api/scene/load_rollout", {"checkpoint": SHIPPED, "num_envs": 4, "play": False})
    assert r.status_code == 200, r.text
    try:
        envs = r.json()["rollout"]["envs"]
        assert (envs["num_envs"], envs["layout"]) == (4, "grid") and 1.5 <= envs["spacing_m"] <= 2.5
        cells = grid_cells(4, envs["spacing_m"])
        s = studio.post("/api/scene/step", {"frames": 20}).json()["rollout"]
        per_env, drawn = s["envs"]["per_env"], s["envs"]["drawn"]
        assert [e["episode_step"] for e in per_env] == [20] * 4
        # The scene draws envs 1..3 (15 body meshes each, one batched mesh per body), each on its cell.
        assert (
            drawn["bodies"] == 15 and len(drawn["at"]) == 3 and drawn["labels"] == [f"{i}: 0 falls" for i in range(4)]
        )
        at = np.array([e["at"] for e in per_env])
        assert np.allclose(at[1:], drawn["at"], atol=1e-3)
        off_cell = at[:, :2] - cells[:, :2]  # where each root is in its own env (env-local)
        assert np.abs(off_cell).max() < 0.8, off_cell
        for i, j in itertools.combinations(range(4), 2):
            assert np.linalg.norm(at[i, :2] - at[j, :2]) > 1.2  # apart on the grid, not on one spot
            # Different starts (each env draws its own clip time): different poses after 20 steps.
            assert np.abs(off_cell[i] - off_cell[j]).max() > 1e-3 or abs(at[i, 2] - at[j, 2]) > 1e-3
        assert len({round(e["episode_return"], 4) for e in per_env}) == 4

        pushed = studio.post("/api/scene/rollout/push", {"force": [0, 3000, 0], "duration_s": 0.5, "env": 2})
        assert pushed.status_code == 200, pushed.text
        assert pushed.json()["rollout"]["push"]["last"]["env"] == 2

        def step_envs() -> dict:
            return studio.post("/api/scene/step", {"frames": 1}).json()["rollout"]["envs"]

        fell = wait_for(lambda: (e := step_envs())["per_env"][2]["falls"] and e, 60, "env 2 to fall after its push")
        assert [e["falls"] for e in fell["per_env"]] == [0, 0, 1, 0]  # counted for env 2 alone
        assert fell["per_env"][2]["episodes"] == 1 and fell["per_env"][2]["mean_return"] is not None
        assert fell["per_env"][2]["marked"] and fell["drawn"]["red"] == [False, True, False]
        assert fell["drawn"]["labels"][2] == "2: 1 fall"
        later = studio.post("/api/scene/step", {"frames": 45}).json()["rollout"]["envs"]  # 1.5 s on: unmarked
        assert not later["per_env"][2]["marked"] and later["drawn"]["red"] == [False, False, False]
        assert later["per_env"][2]["episode_step"] > 0  # it restarted on its own
        assert later["per_env"][0]["episode_step"] == fell["per_env"][0]["episode_step"] + 45  # env 0 went on

        # Scrubbing back shows each env's figures as of the frame shown, not the live ones.
        back = studio.post("/api/scene/seek", {"time": 20 / 30}).json()["rollout"]["envs"]
        assert [(e["episode_step"], e["episodes"], e["falls"]) for e in back["per_env"]] == [(20, 0, 0)] * 4
        assert back["drawn"]["labels"] == [f"{i}: 0 falls" for i in range(4)]
        assert [round(e["episode_return"], 4) for e in back["per_env"]] == [
            round(e["episode_return"], 4) for e in per_env
        ]
        fell_step = fell["per_env"][0]["episode_step"]
        again = studio.post("/api/scene/seek", {"time": fell_step / 30}).json()["rollout"]["envs"]
        assert [e["falls"] for e in again["per_env"]] == [0, 0, 1, 0] and again["drawn"]["labels"][2] == "2: 1 fall"
    finally:
        studio.post("/api/scene/rollout/close")


def test_overlay_and_one_env(studio: StudioProcess) -> None:
    body = {"checkpoint": SHIPPED, "num_envs": 2, "layout": "overlay", "play": False}
    r = studio.post("/api/scene/load_rollout", body)
    assert r.status_code == 200, r.text
    try:
        envs = r.json()["rollout"]["envs"]
        assert envs["layout"] == "overlay" and envs["drawn"]["labels"] == []
        at = np.array([e["at"] for e in envs["per_env"]])
        assert np.linalg.norm(at[0, :2] - at[1, :2]) < 0.8  # both where they are simulated: one spot
    finally:
        studio.post("/api/scene/rollout/close")
    one = studio.post("/api/scene/load_rollout", {"checkpoint": SHIPPED, "play": False}).json()["rollout"]
    try:
        assert one["envs"]["num_envs"] == 1 and one["envs"]["drawn"] is None and one["figures"] == []
    finally:
        studio.post("/api/scene/rollout/close")


@pytest.mark.parametrize(
    ("extra", "code", "says"),
    [
        ({"num_envs": 0}, 422, "num_envs"),
        ({"num_envs": 17}, 422, "num_envs"),
        ({"num_envs": "many"}, 422, "num_envs"),
        ({"layout": "rows"}, 422, "layout"),
        ({"num_envs": 2, "b_checkpoint": SHIPPED}, 400, "one env a side"),
    ],
)
def test_bad_num_envs_and_layout_are_one_line(studio: StudioProcess, extra: dict, code: int, says: str) -> None:
    r = studio.post("/api/scene/load_rollout", {"checkpoint": SHIPPED, "play": False, **extra})
    assert r.status_code == code, r.text
    assert says in _one_line(r)


def test_a_push_of_an_env_it_lacks_is_one_line(studio: StudioProcess) -> None:
    r = studio.post("/api/scene/load_rollout", {"checkpoint": SHIPPED, "num_envs": 2, "play": False})
    assert r.status_code == 200, r.text
    try:
        r = studio.post("/api/scene/rollout/push", {"force": [0, 500, 0], "env": 2})
        assert r.status_code == 400 and "env must be 0 to 1" in _one_line(r)
    finally:
        studio.post("/api/scene/rollout/close")
