"""Rollouts and checkpoint inspection through the real server: load a checkpoint's rollout, drive it
with the scene commands, read its state and reward-term history; refuse checkpoints that do not fit
(one line, HTTP 400); inspect checkpoints and check them against env configs and characters."""

from __future__ import annotations

import dataclasses
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from mimickit.anim.motion import load_motion, save_motion
from mimickit.envs.deepmimic_rewards import TERM_NAMES
from mimickit.learning.checkpoint import read_checkpoint, split_train_state
from mimickit.util.paths import PROJECT_DATA_DIR
from tests.studio.conftest import ENV_YAML, StudioProcess, wait_for, write_arg_file, write_checkpoint_dir

pytestmark = pytest.mark.integration

TERMS = set(TERM_NAMES)  # every DeepMimic term (deepmimic_rewards.py), so a new one needs no edit here


def state(studio: StudioProcess) -> dict:
    return studio.get("/api/scene/state").json()


def test_rollout_of_a_checkpoint(studio: StudioProcess, demo_checkpoint: Path) -> None:
    r = studio.post("/api/scene/load_rollout", {"checkpoint": str(demo_checkpoint)})
    assert r.status_code == 200, r.text
    s = r.json()
    assert s["mode"] == "rollout" and s["playing"] and s["fps"] == 30.0
    info = s["rollout"]
    assert info["checkpoint"] == str(demo_checkpoint) and info["env_config"].endswith("ckpt-demo/env_config.yaml")
    assert info["checkpoint_mtime"] == demo_checkpoint.stat().st_mtime
    try:
        moved = wait_for(lambda: (st := state(studio))["rollout"]["step"] >= 20 and st, 15, "the rollout to step")
        # An untrained policy falls often, and an episode's first frame has no reward: the newest terms.
        assert set(moved["rollout"]["latest"]["reward_terms"]) == TERMS and moved["updates"] >= 20
        assert set(moved["rollout"]["reward_weights"]) == TERMS
        # An untrained policy falls: episodes end and start again by themselves.
        wait_for(lambda: state(studio)["rollout"]["episodes"], 20, "an episode to end and reset")

        # Played: how fast, measured (a slow machine shows below 1); paused: none.
        assert 0 < state(studio)["rollout"]["real_time_factor"] < 5
        paused = studio.post("/api/scene/pause").json()  # the clip player's commands drive the rollout
        assert not paused["playing"] and paused["rollout"]["real_time_factor"] is None
        step = paused["rollout"]["step"]
        assert studio.post("/api/scene/step", {"frames": 2}).json()["rollout"]["step"] == step + 2
        back = studio.post("/api/scene/seek", {"frame": 3}).json()
        assert back["frame"] == 3 and not back["rollout"]["live"] and back["rollout"]["step"] == step + 2
        assert studio.post("/api/scene/step", {"frames": -1}).json()["frame"] == 2

        h = studio.get("/api/scene/rollout/history", params={"since": step - 3}).json()
        assert [row["step"] for row in h["rows"]][-1] == step + 2 and set(h["rows"][-1]["terms"]) == TERMS
        reset = studio.post("/api/scene/rollout/reset").json()
        assert reset["rollout"]["live"] and reset["rollout"]["episode_step"] == 0
        played = studio.post("/api/scene/play").json()
        assert played["playing"] and played["rollout"]["live"]
    finally:
        closed = studio.post("/api/scene/rollout/close").json()
    assert closed["mode"] == "clip"
    # The clip the label names is drawn again (the view was empty after a close until a clip was loaded).
    stepped = studio.post("/api/scene/step", {"frames": 1}).json()  # a state published after the close
    assert stepped["clip"] and stepped["drawn"] == stepped["char"]
    assert studio.get("/api/scene/rollout/history").status_code == 409


def test_the_rollout_says_what_training_its_weights_have_seen(studio: StudioProcess, demo_checkpoint: Path) -> None:
    shipped = PROJECT_DATA_DIR / "models" / "deepmimic_humanoid_demo_model.pt"
    _, train_state = split_train_state(read_checkpoint(shipped, "cpu"))
    r = studio.post("/api/scene/load_rollout", {"checkpoint": str(shipped), "play": False})
    assert r.status_code == 200, r.text
    info = r.json()["rollout"]
    assert (info["iteration"], info["samples"]) == (train_state["iteration"], train_state["samples"])
    assert info["samples"] > 1_000_000  # trained: not a fresh agent's zeros
    fresh = studio.post("/api/scene/load_rollout", {"checkpoint": str(demo_checkpoint), "play": False}).json()
    assert (fresh["rollout"]["iteration"], fresh["rollout"]["samples"]) == (0, 0)  # saved before any training
    studio.post("/api/scene/rollout/close")


def test_clip_replaces_the_rollout(studio: StudioProcess, demo_checkpoint: Path) -> None:
    assert (
        studio.post("/api/scene/load_rollout", {"checkpoint": str(demo_checkpoint), "play": False}).status_code == 200
    )
    s = studio.post("/api/scene/load_clip", {"path": "data/motions/humanoid_demo_squat.pkl"}).json()
    assert s["mode"] == "clip" and s["clip"].endswith("humanoid_demo_squat.pkl")
    assert state(studio)["mode"] == "clip"


def test_checkpoints_that_do_not_fit_are_refused(studio: StudioProcess, misfit_checkpoint: Path) -> None:
    r = studio.post("/api/scene/load_rollout", {"checkpoint": str(misfit_checkpoint)})
    assert r.status_code == 400
    detail = r.json()["detail"]
    assert "\n" not in detail and "does not fit" in detail and "observation size differs" in detail
    # A run of the fake trainer: its model.pt is not a torch checkpoint.
    write_arg_file(studio.runs_dir, "two", rows=2, period=0.05)
    run = studio.post("/api/runs", {"arg_file": str(studio.runs_dir / "args" / "two.txt")}).json()
    wait_for(lambda: studio.get(f"/api/runs/{run['id']}").json()["status"] == "finished", what="the fake run")
    r = studio.post("/api/scene/load_rollout", {"run_id": run["id"]})
    assert r.status_code == 400 and "no env_config and agent_config beside it" in r.json()["detail"]
    configs = {
        "env_config": str(ENV_YAML),
        "agent_config": "data/agents/deepmimic_humanoid_ppo_agent.yaml",
        "engine_config": "data/engines/mujoco_engine.yaml",
    }
    r = studio.post("/api/scene/load_rollout", {"run_id": run["id"], **configs})
    assert r.status_code == 400 and "not a readable checkpoint" in r.json()["detail"]
    assert studio.post("/api/scene/load_rollout", {"run_id": 9999}).status_code == 404
    assert studio.post("/api/scene/load_rollout", {}).status_code == 422
    outside = studio.post("/api/scene/load_rollout", {"checkpoint": "/etc/passwd"})
    assert outside.status_code == 403
    assert state(studio)["mode"] == "clip"  # nothing was replaced


def test_inspect_checkpoints(studio: StudioProcess, demo_checkpoint: Path, misfit_checkpoint: Path) -> None:
    listed = studio.get("/api/checkpoints").json()
    assert str(demo_checkpoint) in [c["path"] for c in listed]

    r = studio.get("/api/checkpoints/inspect", params={"path": str(demo_checkpoint)})
    assert r.status_code == 200, r.text
    c = r.json()
    assert (c["agent"], c["obs_size"], c["action_size"], c["fit"]) == ("PPO", 464, 28, None)
    assert c["networks"]["actor"][0]["shape"] == [1024, 464]
    assert c["normalizers"]["obs"]["size"] == 464 and c["normalizers"]["action"]["size"] == 28
    assert c["train_state"]["agent_name"] == "PPO"

    fits = studio.get(
        "/api/checkpoints/inspect",
        params={"path": str(demo_checkpoint), "env_config": "data/envs/deepmimic_humanoid_env.yaml"},
    ).json()["fit"]
    assert fits["fits"] and (fits["obs_size"], fits["action_size"]) == (464, 28)
    misfit = studio.get(
        "/api/checkpoints/inspect", params={"path": str(misfit_checkpoint), "env_config": str(ENV_YAML)}
    ).json()["fit"]
    assert not misfit["fits"] and "observations of" in misfit["message"] and "gives 464" in misfit["message"]
    char = studio.get(
        "/api/checkpoints/inspect", params={"path": str(demo_checkpoint), "char": "data/assets/humanoid/humanoid.xml"}
    ).json()["fit"]
    assert char["fits"] and char["action_size"] == 28

    assert studio.get("/api/checkpoints/inspect", params={"path": "/etc/passwd"}).status_code == 403
    for key, odd in (("env_config", studio.runs_dir), ("engine_config", studio.runs_dir / "registry.sqlite")):
        given = {"env_config": "data/envs/deepmimic_humanoid_env.yaml", key: str(odd)}  # a folder, the registry
        r = studio.get("/api/checkpoints/inspect", params={"path": str(demo_checkpoint), **given})
        assert r.status_code == 400 and r.json()["detail"].startswith(key), r.text
    fake = studio.runs_dir / "fake.pt"
    fake.write_text(json.dumps({"iteration": 1}))
    r = studio.get("/api/checkpoints/inspect", params={"path": str(fake)})
    assert r.status_code == 400 and "not a readable checkpoint" in r.json()["detail"]


def test_shipped_demo_model_rolls_out_with_its_arg_file(studio: StudioProcess) -> None:
    """A fresh install shows a live policy: the shipped model is listed and rolls out on the configs
    its `.txt` arg file names, and it stays up longer than an untrained policy (~1 s)."""
    shipped = "data/models/deepmimic_humanoid_demo_model.pt"
    listed = {c["path"]: c for c in studio.get("/api/checkpoints").json()}
    assert listed[shipped]["has_configs"], listed[shipped]
    r = studio.post("/api/scene/load_rollout", {"checkpoint": shipped})
    assert r.status_code == 200, r.text
    assert r.json()["rollout"]["env_config"].endswith("data/envs/deepmimic_humanoid_env.yaml")
    try:
        s = wait_for(lambda: (st := state(studio))["rollout"]["step"] >= 200 and st, 40, "200 policy steps")["rollout"]
        longest = max([e["steps"] for e in s["episodes"]] + [s["episode_step"]])
        assert longest >= 60, f"an untrained policy falls after ~30 steps; this one's episodes: {s['episodes']}"
    finally:
        studio.post("/api/scene/rollout/close")


def test_the_state_describes_the_frame_shown_and_play_goes_on_from_it(
    studio: StudioProcess, demo_checkpoint: Path
) -> None:
    assert studio.post("/api/scene/load_rollout", {"checkpoint": str(demo_checkpoint)}).status_code == 200
    try:
        wait_for(lambda: state(studio)["rollout"]["step"] >= 40, 20, "40 rollout steps")
        studio.post("/api/scene/pause")
        back = studio.post("/api/scene/seek", {"frame": 5}).json()
        info = back["rollout"]
        assert not info["live"] and info["latest"]["step"] > info["shown"]["step"]
        for key in ("episode", "episode_step", "episode_return", "reward"):
            assert info[key] == info["shown"][key], key  # the label's values are the shown frame's
        assert info["reward_terms"] == info["shown"]["reward_terms"]
        latest = info["latest"]["step"]
        played = studio.post("/api/scene/play").json()
        assert played["playing"] and not played["rollout"]["live"] and played["frame"] < played["num_frames"] - 1
        moved = wait_for(lambda: (st := state(studio))["frame"] > 8 and st, 10, "history to play on")
        assert moved["rollout"]["latest"]["step"] == latest or moved["rollout"]["live"]  # no jump to the end
        wait_for(lambda: state(studio)["rollout"]["latest"]["step"] > latest, 20, "the live end to go on")
    finally:
        studio.post("/api/scene/rollout/close")


def test_deleting_a_run_stops_its_rollout(studio: StudioProcess) -> None:
    write_arg_file(studio.runs_dir, "to_delete", rows=2, period=0.05)
    run = studio.post("/api/runs", {"arg_file": str(studio.runs_dir / "args" / "to_delete.txt")}).json()
    wait_for(lambda: studio.get(f"/api/runs/{run['id']}").json()["status"] == "finished", what="the fake run")
    write_checkpoint_dir(Path(run["out_dir"]))  # a real checkpoint and its configs in the run's folder
    r = studio.post("/api/scene/load_rollout", {"run_id": run["id"]})
    assert r.status_code == 200, r.text
    assert studio.client.delete(f"/api/runs/{run['id']}").status_code == 204
    s = state(studio)
    assert s["mode"] == "clip" and "rollout" not in s
    assert studio.get("/api/scene/rollout/history").status_code == 409


def test_follow_keeps_a_climbing_reference_in_view(
    studio: StudioProcess, demo_checkpoint: Path, test_data: Path
) -> None:
    """A rollout whose reference climbs (the ghost rises ~2 m): following lowers the ground under it."""
    climb = ENV_YAML.read_text().replace(
        'motion_file: "data/motions/humanoid_demo_squat.pkl"',
        'motion_file: "data/motions/humanoid/parc/humanoid_climb00.pkl"',
    )
    ckpt = write_checkpoint_dir(studio.runs_dir / "ckpt-climb", climb, save_model=False)
    shutil.copyfile(demo_checkpoint, ckpt)  # same character and observations: the demo's weights fit
    assert studio.post("/api/scene/load_rollout", {"checkpoint": str(ckpt)}).status_code == 200
    try:
        high = wait_for(lambda: (st := state(studio))["rollout"]["follow_height"] > 0.5 and st, 40, "a raised view")
        assert high["follow"]
    finally:
        studio.post("/api/scene/rollout/close")


SHIPPED = "data/models/deepmimic_humanoid_demo_model.pt"


def fake_run_with_checkpoint(studio: StudioProcess, name: str) -> dict:
    """A finished fake run whose folder then gets an untrained checkpoint and its configs."""
    write_arg_file(studio.runs_dir, name, rows=2, period=0.05)
    run = studio.post("/api/runs", {"arg_file": str(studio.runs_dir / "args" / f"{name}.txt")}).json()
    wait_for(lambda: studio.get(f"/api/runs/{run['id']}").json()["status"] == "finished", what="the fake run")
    write_checkpoint_dir(Path(run["out_dir"]))
    return run


def test_ab_rollout_of_two_checkpoints(studio: StudioProcess) -> None:
    """A/B: the shipped demo model (A) and a run's untrained checkpoint (B) side by side from the same clip
    starts: B's state, figure and reward rows beside A's; the scene commands move both; a newer B
    checkpoint starts a new pair; deleting B's run stops the pair."""
    run = fake_run_with_checkpoint(studio, "ab_b")
    r = studio.post("/api/scene/load_rollout", {"checkpoint": SHIPPED, "b_run_id": run["id"]})
    assert r.status_code == 200, r.text
    b = r.json()["rollout"]["b"]
    assert b["run_id"] == run["id"] and b["checkpoint"] == str(Path(run["out_dir"]) / "model.pt")
    figures = r.json()["rollout"]["figures"]  # both drawn: a character and a ghost each, labelled A and B
    assert [(f["label"], f["bodies"], f["ghost"]) for f in figures] == [("A", 15, 15), ("B", 15, 15)]
    assert figures[1]["at"][1] - figures[0]["at"][1] == pytest.approx(3.0, abs=0.3)  # B's lane behind A's
    s = wait_for(lambda: (st := state(studio))["rollout"]["b"]["waiting"] and st, 30, "B to fall and wait")["rollout"]
    assert not s["waiting"] and s["b"]["episode"] == s["episode"] == 0  # the trained A goes on in the same pair
    rows = studio.get("/api/scene/rollout/history").json()["rows"]
    assert rows and all(set(row["b"]) == {"reward", "terms"} for row in rows)
    assert rows[0]["b"]["reward"] is not None and rows[-1]["b"]["reward"] is None

    paused = studio.post("/api/scene/pause").json()["rollout"]
    stepped = studio.post("/api/scene/step", {"frames": 2}).json()["rollout"]
    assert stepped["step"] == paused["step"] + 2 and stepped["b"]["waiting"]
    back = studio.post("/api/scene/seek", {"frame": 3}).json()["rollout"]  # both sides at that frame
    assert not back["live"] and back["episode_step"] == back["b"]["episode_step"] == 3 and not back["b"]["waiting"]
    assert back["b"]["reward"] is not None and set(back["b"]["reward_terms"]) == TERMS

    write_checkpoint_dir(Path(run["out_dir"]))  # the trainer wrote a newer B: both start a new pair
    new = wait_for(lambda: (st := state(studio))["rollout"]["b"]["reloads"] == 1 and st, 20, "B reloaded")["rollout"]
    assert new["live"] and new["episode"] == new["b"]["episode"] == 1 and new["episode_step"] == 0
    assert new["reloads"] == 0 and new["b"]["episode_step"] == 0

    assert studio.client.delete(f"/api/runs/{run['id']}").status_code == 204  # B's checkpoint is gone
    assert state(studio)["mode"] == "clip"


def test_ab_rollout_reloads_a_and_takes_b_as_a_checkpoint(studio: StudioProcess) -> None:
    """A from a run, B a checkpoint path (`b_checkpoint`): a newer A starts a new pair too."""
    run = fake_run_with_checkpoint(studio, "ab_a")
    r = studio.post("/api/scene/load_rollout", {"run_id": run["id"], "b_checkpoint": SHIPPED, "play": False})
    assert r.status_code == 200, r.text
    try:
        assert r.json()["rollout"]["b"]["checkpoint"].endswith(SHIPPED) and not r.json()["playing"]
        studio.post("/api/scene/step", {"frames": 5})
        write_checkpoint_dir(Path(run["out_dir"]))
        new = wait_for(lambda: (st := state(studio))["rollout"]["reloads"] == 1 and st, 20, "A reloaded")["rollout"]
        assert new["episode"] == new["b"]["episode"] == 1 and new["b"]["reloads"] == 0
    finally:
        studio.post("/api/scene/rollout/close")


def test_ab_misfits_are_one_line_and_keep_the_rollout_shown(
    studio: StudioProcess, demo_checkpoint: Path, misfit_checkpoint: Path
) -> None:
    """Two Bs given, a B that does not fit its env, one that is no checkpoint, one on another clip and one
    of another kind of env: refused in one line naming the problem, and the rollout shown stays."""
    shown = studio.post("/api/scene/load_rollout", {"checkpoint": str(demo_checkpoint), "play": False})
    assert shown.status_code == 200, shown.text
    clip = load_motion(PROJECT_DATA_DIR / "motions" / "humanoid_demo_squat.pkl")  # a second after it begins
    shifted = studio.runs_dir / "squat_shifted.pkl"
    save_motion(shifted, dataclasses.replace(clip, frames=np.roll(clip.frames, round(clip.fps), axis=0)))
    other_clip = ENV_YAML.read_text().replace("data/motions/humanoid_demo_squat.pkl", str(shifted))
    amp_env = (ENV_YAML.parent / "amp_humanoid_env.yaml").read_text()
    unreadable = write_checkpoint_dir(studio.runs_dir / "ckpt-unreadable", save_model=False)
    unreadable.write_bytes(b"not a checkpoint")
    cases = [
        (str(misfit_checkpoint), "B: .*does not fit.*observation size differs"),
        (str(unreadable), "B: .*not a readable checkpoint"),
        (str(write_checkpoint_dir(studio.runs_dir / "ckpt-shifted", other_clip)), "both must track the same clip"),
        (str(write_checkpoint_dir(studio.runs_dir / "ckpt-amp", amp_env)), "one kind of env: .*B's AMPEnv"),
    ]
    try:
        both = studio.post("/api/scene/load_rollout", {"checkpoint": SHIPPED, "b_run_id": 1, "b_checkpoint": SHIPPED})
        assert both.status_code == 422 and "at most one of" in both.json()["detail"]
        for b, says in cases:
            r = studio.post("/api/scene/load_rollout", {"checkpoint": SHIPPED, "b_checkpoint": b})
            detail = r.json()["detail"]
            assert r.status_code == 400 and "\n" not in detail and re.search(says, detail), (b, r.text)
            after = state(studio)
            assert after["mode"] == "rollout" and after["rollout"]["checkpoint"] == str(demo_checkpoint)
            assert after["rollout"]["b"] is None
    finally:
        studio.post("/api/scene/rollout/close")
