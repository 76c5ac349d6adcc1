"""Pushes in the live rollout through the real server (issue 37): `POST /api/scene/rollout/push` moves the
shipped demo model's character against the same episode without it (`/rollout/reset {"same_start": true}`
starts both from one clip state, and the deterministic policy repeats itself), the push is recorded in
the state and the history rows, and bad pushes are one-line 4xx answers."""

from __future__ import annotations

import pytest

from mimickit.util.paths import PROJECT_DATA_DIR
from tests.studio.conftest import StudioProcess

pytestmark = pytest.mark.integration

DEMO = {
    "checkpoint": str(PROJECT_DATA_DIR / "models" / "deepmimic_humanoid_demo_model.pt"),
    "env_config": str(PROJECT_DATA_DIR / "envs" / "deepmimic_humanoid_env.yaml"),
    "agent_config": str(PROJECT_DATA_DIR / "agents" / "deepmimic_humanoid_ppo_cpu_agent.yaml"),
    "engine_config": str(PROJECT_DATA_DIR / "engines" / "mujoco_engine.yaml"),
}


def episode_root(studio: StudioProcess, push: dict | None) -> tuple[list[float], dict]:
    """From the last episode's start again: 5 steps, the push (if any), 6 more steps (0.2 s); the root
    position then and the state."""
    assert studio.post("/api/scene/rollout/reset", {"same_start": True}).status_code == 200
    assert studio.post("/api/scene/step", {"frames": 5}).status_code == 200
    if push is not None:
        r = studio.post("/api/scene/rollout/push", push)
        assert r.status_code == 200, r.text
    s = studio.post("/api/scene/step", {"frames": 6}).json()
    assert s["rollout"]["episode_step"] == 11, "the episode ended: the comparison needs it to go on"
    return s["root_pos"], s


def test_a_push_moves_the_root_against_the_same_episode_without_it(studio: StudioProcess) -> None:
    r = studio.post("/api/scene/load_rollout", {**DEMO, "play": False})
    assert r.status_code == 200, r.text
    push = r.json()["rollout"]["push"]
    assert push["bodies"][0] == "pelvis" and push["picked"] == "pelvis" and push["max_force_n"] == 5000
    try:
        before, _ = episode_root(studio, None)
        pushed, s = episode_root(studio, {"body": "pelvis", "force": [800, 0, 0], "duration_s": 0.2})
        again, _ = episode_root(studio, None)
        assert again == pytest.approx(before, abs=1e-6)  # the same start and policy: the same episode
        assert pushed[0] - before[0] > 0.1, (before, pushed)  # 800 N along +x for 0.2 s
        last = s["rollout"]["push"]["last"]
        assert last["body"] == "pelvis" and last["force"] == [800.0, 0.0, 0.0] and last["steps"] == 6
        rows = studio.get("/api/scene/rollout/history", params={"since": last["at_step"] - 1}).json()["rows"]
        assert rows[0]["step"] == last["at_step"]
        assert rows[0]["push"] == [{"body": "pelvis", "force": [800.0, 0.0, 0.0], "duration_s": 0.2}]
        assert all(row["push"] is None for row in rows[1:])  # marked where it began only

        # A shove that throws it: the fall is recorded as one after a push.
        studio.post("/api/scene/rollout/reset", {"same_start": True})
        studio.post("/api/scene/rollout/push", {"force": [0, 3000, 0], "duration_s": 0.3})  # the picked body
        fell = studio.post("/api/scene/step", {"frames": 60}).json()["rollout"]["episodes"][-1]
        assert fell["done"] == 1 and 0 < fell["fall_after_push_s"] < 2.0, fell
    finally:
        studio.post("/api/scene/rollout/close")


@pytest.mark.parametrize(
    ("body", "status", "says"),
    [
        ({"body": "tail", "force": [1, 0, 0]}, 400, "no body 'tail' on the character; its bodies: pelvis"),
        ({"force": [6000, 0, 0]}, 400, "more than a push's 5000 N"),
        ({"force": [1, 0, 0], "duration_s": 5}, 400, "at most 2 s"),
        ({"force": [1, 0, 0], "duration_s": 0}, 400, "above 0"),
        ({"force": [1, 0]}, 422, "force:"),
        ({"force": [1, 0, 0], "torque": [0, 0, 1]}, 422, "unknown key 'torque'"),
    ],
)
def test_bad_pushes_are_one_line_4xx(studio: StudioProcess, body: dict, status: int, says: str) -> None:
    r = studio.post("/api/scene/load_rollout", {**DEMO, "play": False})
    assert r.status_code == 200, r.text
    try:
        bad = studio.post("/api/scene/rollout/push", body)
        assert bad.status_code == status and says in bad.json()["detail"], bad.text
        assert "\n" not in bad.json()["detail"]
        nan = studio.client.post(
            "/api/scene/rollout/push", content=b'{"force": [NaN, 0, 0]}', headers={"Content-Type": "application/json"}
        )
        assert nan.status_code in (400, 422) and "\n" not in nan.json()["detail"], nan.text
    finally:
        studio.post("/api/scene/rollout/close")
    assert studio.post("/api/scene/rollout/push", {"force": [1, 0, 0]}).status_code == 409
