"""Scene commands on the real server: load a clip, play, pause, step, seek; the state says what is drawn."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from studio.scene.clip_pose import pose_clip
from studio.scene.view import support_height
from tests.studio.conftest import StudioProcess, wait_for

pytestmark = pytest.mark.integration

WALK = "data/motions/humanoid/humanoid_walk.pkl"


def command(studio: StudioProcess, name: str, body: object = None) -> dict:
    r = studio.post(f"/api/scene/{name}", body)
    assert r.status_code == 200, r.text
    return r.json()


def test_load_play_pause_step_seek(studio: StudioProcess, test_data) -> None:
    s = command(studio, "load_clip", {"path": WALK})
    assert s["clip"].endswith("humanoid/humanoid_walk.pkl") and s["char"].endswith("humanoid/humanoid.xml")
    assert (s["frame"], s["playing"], s["num_frames"], s["fps"]) == (0, False, 125, 120)
    root0 = s["root_pos"]
    assert 0.7 < root0[2] < 1.0  # the pelvis of a standing humanoid

    command(studio, "play")
    moved = wait_for(lambda: (st := studio.get("/api/scene/state").json())["frame"] > 10 and st, what="playback")
    assert moved["playing"] and moved["root_pos"][0] > root0[0]  # it walks forward along +x
    updates_before = moved["updates"]

    paused = command(studio, "pause")
    time.sleep(0.3)
    still = studio.get("/api/scene/state").json()
    assert not still["playing"] and still["frame"] == paused["frame"] and still["updates"] == paused["updates"]
    assert still["updates"] >= updates_before

    stepped = command(studio, "step", {"frames": 1})
    assert stepped["frame"] == (still["frame"] + 1) % 125
    assert command(studio, "step", {"frames": -2})["frame"] == (still["frame"] - 1) % 125

    s = command(studio, "seek", {"frame": 60})
    assert s["frame"] == 60 and s["time"] == pytest.approx(0.5)
    s = command(studio, "seek", {"time": 0.25})
    assert s["frame"] == 30
    assert command(studio, "seek", {"frame": 10_000})["frame"] == 124  # clamped to the clip

    s = command(studio, "configure", {"speed": 2.0, "loop": False, "follow": False})
    assert (s["speed"], s["loop"], s["follow"]) == (2.0, False, False)
    command(studio, "seek", {"frame": 120})
    command(studio, "play")
    end = wait_for(lambda: (st := studio.get("/api/scene/state").json())["playing"] is False and st, what="clip end")
    assert end["frame"] == 124  # a non-looping clip stops on its last frame
    command(studio, "configure", {"speed": 1.0, "loop": True, "follow": True})


def test_foot_contacts_are_reported(studio: StudioProcess, test_data) -> None:
    s = command(studio, "load_clip", {"path": WALK})
    assert set(s["contacts"]) == {"left_foot", "right_foot"}
    seen = set()
    for frame in range(0, 125, 5):
        contacts = command(studio, "seek", {"frame": frame})["contacts"]
        seen.add(tuple(sorted(k for k, v in contacts.items() if v)))
    assert ("left_foot",) in seen and ("right_foot",) in seen  # single support phases of a walk


def test_clip_on_a_character_that_does_not_fit(studio: StudioProcess, test_data) -> None:
    r = studio.post("/api/scene/load_clip", {"path": WALK, "char": "data/assets/go2/go2.xml"})
    assert r.status_code == 400 and "columns" in r.json()["detail"]


def test_other_characters_load(studio: StudioProcess, test_data) -> None:
    for clip in ("data/motions/go2/go2_trot.pkl", "data/motions/humanoid_demo_squat.pkl"):
        s = command(studio, "load_clip", {"path": clip})
        assert s["num_frames"] > 0 and s["frame"] == 0


def test_startup_plays_the_demo_clip_and_clip_none_starts_empty(tmp_path) -> None:
    """What a new user sees first (`make studio`): the project's humanoid playing the demo clip."""
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    server = StudioProcess(tmp_path / "a")
    try:
        state = server.get("/api/scene/state").json()
        assert state["clip"].endswith("data/motions/humanoid_demo_squat.pkl")
        assert state["char"].endswith("data/assets/humanoid/humanoid.xml")
        assert state["playing"] and state["num_frames"] > 1
        assert wait_for(lambda: server.get("/api/scene/state").json()["frame"] != state["frame"], 10)
    finally:
        server.stop()
    server = StudioProcess(tmp_path / "b", None, "--clip", "none")
    try:
        assert server.get("/api/scene/state").json().get("clip") is None
    finally:
        server.stop()


def test_follow_height_keeps_a_climb_in_view_and_the_feet_on_the_ground(test_data) -> None:
    """The level camera follow lowers the ground by: ~2 m at the top of MimicKit's climbing clip, ~0 for
    a walk and the demo squat, and never above the feet (they would sink through the ground)."""
    humanoid = test_data / "assets" / "humanoid" / "humanoid.xml"
    squat = Path(__file__).parents[2] / "data" / "motions" / "humanoid_demo_squat.pkl"
    heights = {}
    for clip in (
        test_data / "motions/humanoid/parc/humanoid_climb00.pkl",
        test_data / WALK.removeprefix("data/"),
        squat,
    ):
        pose = pose_clip(clip, humanoid)
        feet = pose.foot_low_z.min(axis=1)
        h = support_height(feet, pose.fps)
        assert h.shape == (pose.num_frames,) and np.all(h <= feet + 1e-6)
        heights[clip.stem] = (float(h.min()), float(h.max()))
    assert heights["humanoid_climb00"][1] - heights["humanoid_climb00"][0] > 1.5
    for still in ("humanoid_walk", "humanoid_demo_squat"):
        assert max(abs(v) for v in heights[still]) < 0.03, heights[still]
