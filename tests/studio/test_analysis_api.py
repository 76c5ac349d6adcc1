"""Clip analysis (`GET /api/scene/analysis`): a clip's curves are its own DoF values, their finite
differences, its root path and the player's foot contacts; a rollout's are its recorded history, the
reference's (the ghost's, its drawing offset taken off) beside the character's, and the reference's are
what the env's clip gives at each step. An unknown joint is a one-line 400 naming it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from mimickit.anim.mjcf_char_model import load_char_model
from mimickit.anim.motion import load_motion
from mimickit.util.paths import PROJECT_DATA_DIR
from studio.scene.analysis import MAX_JOINTS, analyse_rollout, record
from studio.scene.clip_pose import pose_clip
from studio.scene.rollout import Rollout, source_for_checkpoint
from tests.studio.conftest import StudioProcess

pytestmark = pytest.mark.integration

CLIP = PROJECT_DATA_DIR / "motions" / "humanoid_demo_squat.pkl"
HUMANOID = PROJECT_DATA_DIR / "assets" / "humanoid" / "humanoid.xml"
SHIPPED = PROJECT_DATA_DIR / "models" / "deepmimic_humanoid_demo_model.pt"


def analysis(studio: StudioProcess, joints: str | None = None) -> dict:
    r = studio.get("/api/scene/analysis", params={"joints": joints} if joints else {})
    assert r.status_code == 200, r.text
    return r.json()


def dof_column(joint: str) -> tuple[int, int]:
    j = next(j for j in load_char_model(HUMANOID).joints if j.name == joint)
    return j.dof_idx, j.dof_dim


def test_a_clips_curves_are_its_own_dofs_root_and_contacts(studio: StudioProcess) -> None:
    r = studio.post("/api/scene/load_clip", {"path": "data/motions/humanoid_demo_squat.pkl", "play": False})
    assert r.status_code == 200, r.text
    a = analysis(studio, "right_knee,abdomen")
    motion = load_motion(CLIP)
    n, fps = motion.num_frames, motion.fps
    assert a["mode"] == "clip" and a["ref"] is None and a["picked"] == ["right_knee", "abdomen"]
    assert {"name": "right_knee", "type": "hinge", "dofs": 1} in a["joints"]
    assert {"name": "abdomen", "type": "ball", "dofs": 3} in a["joints"]
    c = a["char"]
    assert len(a["time"]) == n and all(len(c["root"][k]) == n for k in "xyz")
    np.testing.assert_allclose(a["time"], np.arange(n) / fps, atol=1e-5)

    knee, _ = dof_column("right_knee")
    angle = motion.frames[:, 6 + knee]
    np.testing.assert_allclose(c["angle"]["right_knee"], angle, atol=1e-4)  # the clip's own DoF value
    np.testing.assert_allclose(c["velocity"]["right_knee"], np.gradient(angle, 1 / fps), atol=1e-3)
    abdomen, dim = dof_column("abdomen")  # a ball joint: its rotation angle, the exp-map's norm
    np.testing.assert_allclose(
        c["angle"]["abdomen"], np.linalg.norm(motion.frames[:, 6 + abdomen : 6 + abdomen + dim], axis=1), atol=1e-4
    )
    assert all(v >= 0 for v in c["velocity"]["abdomen"])  # its angular speed

    pose = pose_clip(CLIP, HUMANOID)
    np.testing.assert_allclose(np.array([c["root"][k] for k in "xyz"]).T, pose.root_pos, atol=1e-4)
    assert a["feet"] == pose.feet
    for i, foot in enumerate(pose.feet):
        assert c["contacts"][foot] == [bool(pose.contacts(f)[i]) for f in range(n)]

    picked = analysis(studio)["picked"]  # none named: the first hinges
    assert picked and all(j["type"] == "hinge" for j in a["joints"] if j["name"] in picked)


def test_an_unknown_joint_or_too_many_is_one_line_400(studio: StudioProcess) -> None:
    studio.post("/api/scene/load_clip", {"path": "data/motions/humanoid_demo_squat.pkl", "play": False})
    r = studio.get("/api/scene/analysis", params={"joints": "right_knee,tail"})
    assert r.status_code == 400 and "'tail'" in r.json()["detail"] and "\n" not in r.json()["detail"]
    many = ",".join(["right_knee"] * (MAX_JOINTS + 1))
    r = studio.get("/api/scene/analysis", params={"joints": many})
    assert r.status_code == 400 and f"at most {MAX_JOINTS}" in r.json()["detail"]


def test_a_rollouts_curves_are_its_history_with_the_reference_beside(studio: StudioProcess) -> None:
    r = studio.post(
        "/api/scene/load_rollout", {"checkpoint": "data/models/deepmimic_humanoid_demo_model.pt", "play": False}
    )
    assert r.status_code == 200, r.text
    try:
        s = studio.post("/api/scene/step", {"frames": 40}).json()
        a = analysis(studio, "right_knee,abdomen")
        n = s["num_frames"]
        assert a["mode"] == "rollout" and n >= 41 and len(a["time"]) == len(a["episode"]) == n
        for fig in (a["char"], a["ref"]):
            assert all(len(fig["root"][k]) == n for k in "xyz") and len(fig["angle"]["right_knee"]) == n
            assert all(len(v) == n for v in fig["contacts"].values())
        assert a["time"][-1] == pytest.approx(s["time"], abs=1e-4)
        # An episode starts from the reference's state: the character stands where the ghost's clip is
        # (the ghost's 2 m drawing offset taken off), in its pose.
        start = a["episode"].index(a["episode"][-1])
        for k in "xyz":
            assert a["char"]["root"][k][start] == pytest.approx(a["ref"]["root"][k][start], abs=1e-3)
        assert a["char"]["angle"]["right_knee"][start] == pytest.approx(
            a["ref"]["angle"]["right_knee"][start], abs=1e-3
        )
        # ... and then the policy's own motion differs from it.
        assert a["char"]["angle"]["right_knee"] != a["ref"]["angle"]["right_knee"]
    finally:
        studio.post("/api/scene/rollout/close")


@pytest.mark.slow
def test_the_reference_series_is_the_envs_clip_at_each_step() -> None:
    r = Rollout(source_for_checkpoint(SHIPPED), history_s=2.0)
    try:
        env, lib = r.env, r.env.motion_lib
        expected = []  # the clip at the env's motion time, read from the env, not from the ghost
        for step in range(20):
            if step:
                r.step()
            f = lib.calc_motion_frame(env.get_motion_ids(), env.get_motion_time())
            expected.append((f.root_pos[0].numpy(), lib.joint_rot_to_dof(f.joint_rot)[0].numpy()))
        a = analyse_rollout(record(r), ["right_knee", "abdomen"])
    finally:
        r.close()
    got = a["ref"]
    n = len(expected)
    assert len(a["time"]) == n
    root = np.array([got["root"][k] for k in "xyz"]).T
    np.testing.assert_allclose(root, [e[0] for e in expected], atol=1e-4)
    knee, _ = dof_column("right_knee")
    np.testing.assert_allclose(got["angle"]["right_knee"], [e[1][knee] for e in expected], atol=1e-4)
    abdomen, dim = dof_column("abdomen")
    norms = [float(torch.linalg.norm(torch.from_numpy(e[1][abdomen : abdomen + dim]))) for e in expected]
    np.testing.assert_allclose(got["angle"]["abdomen"], norms, atol=1e-4)


def test_nothing_loaded_is_409(tmp_path: Path) -> None:
    server = StudioProcess(tmp_path, None, "--clip", "none")
    try:
        r = server.get("/api/scene/analysis")
        assert r.status_code == 409 and "nothing to analyse" in r.json()["detail"]
    finally:
        server.stop()
