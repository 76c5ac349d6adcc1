"""Per-body tracking error of a live rollout: each recorded step's errors against a hand computation from
the recorded pose (the character's bodies against the ghost's in the env's own MuJoCo model), the history
rows and the state that carry them, the scene's bodies coloured by them on a real viser server, and the
state of a real server rolling out the shipped demo model."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import viser

from studio.scene.rollout import Frame, Rollout, RolloutPlayer, source_for_checkpoint
from studio.scene.view import BODY_ERROR_SCALE_M, BODY_ERROR_STOPS, StudioScene, error_colour
from tests.studio.conftest import StudioProcess, wait_for, write_checkpoint_dir

pytestmark = pytest.mark.slow

SHIPPED = "data/models/deepmimic_humanoid_demo_model.pt"


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_checkpoint_dir(tmp_path_factory.mktemp("body_error") / "run")


@pytest.fixture
def rollout(ckpt: Path):
    r = Rollout(source_for_checkpoint(ckpt), history_s=2.0)
    yield r
    r.close()


def by_hand(r: Rollout, frame: Frame) -> np.ndarray:
    """The errors from a recorded pose alone: the ghost stands at the reference + ref_char_offset."""
    xpos, _ = r.pose(frame)
    sim = xpos[r.char_bodies]
    ref = xpos[r.ghost_bodies] - np.asarray(r.env.config.ref_char_offset)
    rel = np.linalg.norm((sim - sim[:1]) - (ref - ref[:1]), axis=-1)
    return np.concatenate([[np.linalg.norm(sim[0] - ref[0])], rel[1:]])


def test_each_step_records_the_errors_against_the_ghost(rollout: Rollout) -> None:
    r = rollout
    assert r.body_names == r.env.char_model.get_body_names() and len(r.char_bodies) == len(r.body_names) == 15
    start = r.history[-1]
    assert start.body_error is not None and start.body_error.max() < 1e-4  # a reset: the character is the reference
    for _ in range(25):  # an untrained policy drifts off the reference
        r.step()
    frames = list(r.history)[-25:]
    for f in frames:
        np.testing.assert_allclose(f.body_error, by_hand(r, f), atol=2e-4)
    assert max(float(f.body_error.max()) for f in frames) > 0.02
    j = r.body_error_json(frames[-1])
    assert j["bodies"] == r.body_names and j["errors_m"] == pytest.approx(frames[-1].body_error.tolist(), abs=1e-5)
    assert j["mean_m"] == pytest.approx(float(frames[-1].body_error.mean()), abs=1e-5)
    assert j["scale_m"] == BODY_ERROR_SCALE_M and j["stops"] == [list(c) for c in BODY_ERROR_STOPS]


def test_rows_state_and_scene_colours(rollout: Rollout) -> None:
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        scene = StudioScene(server)
        rp = RolloutPlayer(rollout, scene)
        try:
            colours = scene.body_colours()
            assert set(colours) == set(int(b) for b in rollout.char_bodies)  # every body of the humanoid has geoms
            assert set(colours.values()) == {BODY_ERROR_STOPS[0]}  # the reset pose: no error anywhere
            rp.step(20)
            s = rp.snapshot()["rollout"]["body_error"]
            shown = rollout.history[-1]
            assert s["errors_m"] == pytest.approx(shown.body_error.tolist(), abs=1e-5)
            colours = scene.body_colours()
            for b, e in zip(rollout.char_bodies, shown.body_error, strict=True):
                assert colours[int(b)] == error_colour(e), rollout.body_names[list(rollout.char_bodies).index(b)]
            assert len(set(colours.values())) > 1  # the bodies differ
            assert s["colours"] == [list(colours[int(b)]) for b in rollout.char_bodies]  # the page's bars: the same
            rows = rp.history_rows(since_step=shown.step - 5)
            assert rows[-1]["body_error"] == pytest.approx(shown.body_error.tolist(), abs=1e-5)

            rp.seek(frame=2)  # a history frame: its own errors, in the state and on the character
            old = rollout.history[2]
            shown_json = rp.snapshot()["rollout"]["body_error"]
            assert shown_json["errors_m"] == pytest.approx(old.body_error.tolist(), abs=1e-5)
            assert scene.body_colours()[int(rollout.char_bodies[5])] == error_colour(old.body_error[5])
        finally:
            rp.close()
    finally:
        server.stop()


def test_error_colour_scale() -> None:
    assert error_colour(0.0) == BODY_ERROR_STOPS[0] and error_colour(-1.0) == BODY_ERROR_STOPS[0]
    assert error_colour(BODY_ERROR_SCALE_M / 2) == BODY_ERROR_STOPS[1]
    assert error_colour(BODY_ERROR_SCALE_M) == BODY_ERROR_STOPS[2] == error_colour(5.0)
    quarter = error_colour(BODY_ERROR_SCALE_M / 4)
    low, mid = BODY_ERROR_STOPS[0], BODY_ERROR_STOPS[1]
    assert quarter == tuple(int((a + b) / 2 + 0.5) for a, b in zip(low, mid, strict=True))  # halves round up


@pytest.mark.integration
def test_a_server_rollout_of_the_demo_model_carries_the_errors(studio: StudioProcess) -> None:
    r = studio.post("/api/scene/load_rollout", {"checkpoint": SHIPPED})
    assert r.status_code == 200, r.text
    try:
        s = wait_for(lambda: (st := studio.get("/api/scene/state").json())["rollout"]["step"] >= 60 and st, 40, "steps")
        err = s["rollout"]["body_error"]
        assert err["bodies"][0] == "pelvis" and len(err["bodies"]) == len(err["errors_m"]) == 15
        assert all(0.0 <= e < 2.0 for e in err["errors_m"]) and max(err["errors_m"]) > 0.0
        assert err["mean_m"] == pytest.approx(sum(err["errors_m"]) / 15, abs=1e-4)
        assert "root-relative" in err["measure"]
        h = studio.get("/api/scene/rollout/history", params={"since": s["rollout"]["step"] - 10}).json()
        assert all(len(row["body_error"]) == 15 for row in h["rows"])
        paused = studio.post("/api/scene/pause").json()
        back = studio.post("/api/scene/seek", {"frame": 3}).json()  # a history frame: its own errors
        assert back["rollout"]["body_error"]["errors_m"] != paused["rollout"]["body_error"]["errors_m"]
    finally:
        studio.post("/api/scene/rollout/close")
