"""Live rollouts in-process (no server, no drawing): the policy stepping one env with its ghost, the
recorded history, episode resets, the player's pace (counted in ticks of a simulated clock) and
commands, reloading a newer checkpoint; and checkpoint inspection."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from mimickit.envs.deepmimic_rewards import TERM_NAMES
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_ROOT
from studio.runs.checkpoints import (
    MOTION_FILE,
    agent_type,
    check_fit_char,
    check_fit_env,
    configs_beside,
    fit_message,
    inspect_checkpoint,
)
from studio.scene.rollout import Rollout, RolloutPlayer, source_for_checkpoint
from studio.scene.thread import SceneThread
from tests.conftest import PROJECT_HUMANOID
from tests.studio.conftest import (
    ENGINE_YAML,
    ENV_YAML,
    shipped_style_model,
    smaller_obs_env_yaml,
    wait_for,
    write_checkpoint_dir,
    write_demo_dataset,
)

pytestmark = pytest.mark.slow

TERMS = set(TERM_NAMES)  # every DeepMimic term (deepmimic_rewards.py), so a new one needs no edit here


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_checkpoint_dir(tmp_path_factory.mktemp("rollout") / "run")


@pytest.fixture(scope="module")
def other_obs_ckpt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_checkpoint_dir(tmp_path_factory.mktemp("rollout") / "other", smaller_obs_env_yaml())


@pytest.fixture
def rollout(ckpt: Path):
    r = Rollout(source_for_checkpoint(ckpt), history_s=2.0)
    yield r
    r.close()


def test_source_reads_the_run_folder(ckpt: Path, tmp_path: Path) -> None:
    src = source_for_checkpoint(ckpt)
    assert src.env_config == ckpt.parent / "env_config.yaml" and src.agent_config == ckpt.parent / "agent_config.yaml"
    assert src.engine_config == ckpt.parent / "engine_config.yaml" and src.data_dir is None
    (ckpt.parent / "int_models").mkdir(exist_ok=True)  # an intermediate model: the configs are one up
    inner = ckpt.parent / "int_models" / "model_0000000001.pt"
    shutil.copyfile(ckpt, inner)
    assert source_for_checkpoint(inner).env_config == src.env_config
    lone = tmp_path / "lone.pt"
    shutil.copyfile(ckpt, lone)
    with pytest.raises(MimicKitError, match="no env_config and agent_config beside it"):
        source_for_checkpoint(lone)
    given = source_for_checkpoint(lone, env_config=ENV_YAML, agent_config=src.agent_config)
    assert given.env_config == ENV_YAML


@pytest.mark.integration
def test_source_takes_the_data_dir_of_a_cli_run(tmp_path: Path, test_data: Path) -> None:
    """A run trained from the CLI with --data_dir rolls out with that folder, read from its args.json."""
    out = tmp_path / "run"
    argv = ["--arg_file", str(PROJECT_ROOT / "args" / "deepmimic_humanoid_demo_ppo_args.txt"), "--num_envs", "2"]
    argv += ["--max_samples", "2", "--out_dir", str(out), "--data_dir", str(test_data), "--rand_seed", "1"]
    done = subprocess.run([sys.executable, "-m", "mimickit.cli", "train", *argv], cwd=tmp_path, capture_output=True)
    assert done.returncode == 0, done.stderr.decode()[-2000:]
    assert source_for_checkpoint(out / "model.pt").data_dir == test_data.resolve()


def test_a_models_arg_file_motion_file_is_the_clip_it_rolls_out_on(tmp_path: Path) -> None:
    """A shipped model's arg file that names `--motion_file` rolls out on that clip, not the env config's;
    an env config given with the request takes its own clip; a missing clip is one line naming it."""
    _, short = write_demo_dataset(tmp_path / "clips")
    model = shipped_style_model(tmp_path / "a", "--motion_file", str(short))
    assert configs_beside(model)[MOTION_FILE] == str(short)
    source = source_for_checkpoint(model)
    assert source.motion_file == short and source.to_json()["motion_file"] == str(short)
    r = Rollout(source, history_s=1.0)
    try:
        assert [Path(f) for f in r.motion_files] == [short]
    finally:
        r.close()
    assert source_for_checkpoint(model, env_config=ENV_YAML).motion_file is None
    plain = source_for_checkpoint(shipped_style_model(tmp_path / "b"))
    assert plain.motion_file is None
    r = Rollout(plain, history_s=1.0)
    try:
        assert [Path(f).name for f in r.motion_files] == ["humanoid_demo_squat.pkl"]  # the env config's
    finally:
        r.close()
    missing = shipped_style_model(tmp_path / "c", "--motion_file", "data/motions/no_such_clip.pkl")
    with pytest.raises(MimicKitError, match="x_model.txt: --motion_file data/motions/no_such_clip.pkl: file not found"):
        source_for_checkpoint(missing)


def test_rollout_steps_records_and_resets(rollout: Rollout) -> None:
    r = rollout
    assert r.control_freq == pytest.approx(30.0)
    assert len(r.ghost_bodies) == 15 and r.root_body not in r.ghost_bodies  # the reference is in the model
    assert set(r.reward_weights) == TERMS
    first = r.history[-1]
    assert first.reward is None and first.step == 0  # the pose the episode starts from
    for _ in range(400):  # an untrained policy falls within a few seconds
        frame = r.step()
        if frame.done:
            break
    assert frame.done, "no episode ended in 400 steps"
    assert set(frame.terms) == TERMS and all(0.0 <= v <= 1.0 for v in frame.terms.values())
    assert r.episodes[-1].steps == frame.episode_step and r.episodes[-1].ret == pytest.approx(frame.episode_return)
    assert r.episode == 1 and r.history[-1].episode == 1 and r.history[-1].reward is None  # reset at once
    for _ in range(70):
        r.step()
    assert len(r.history) == 60 and r.history[0].step > 0  # 2 s at 30 Hz: older steps are forgotten
    # The ghost stands where the env's reference is, offset by ref_char_offset (2 m along x).
    xpos, _ = r.pose(r.history[-1])
    ref = r.env.get_ref_state()["root_pos"][0].numpy()
    np.testing.assert_allclose(xpos[r.ghost_bodies[0]], ref + np.array([2.0, 0.0, 0.0]), atol=1e-5)
    # A recorded frame is drawn from its qpos: scrubbing back shows the pose of that step.
    old = r.history[5]
    np.testing.assert_allclose(r.pose(old)[0][r.root_body], old.qpos[:3], atol=1e-6)


def played(rollout: Rollout, owner: SceneThread) -> RolloutPlayer:
    """`rollout` playing on its own scene thread (as the studio's, without a viser scene)."""
    rp = owner.call(RolloutPlayer, rollout, None, owner, play=True)
    owner.call(owner.drive, rp)
    return rp


def test_player_steps_at_the_control_rate_without_bursts(rollout: Rollout) -> None:
    """The pace counted in ticks of a simulated clock, not measured in seconds: ticks 4 times a control
    period step once per period (× speed), a late tick catches up at most a few steps, a pause stops it."""
    rp = RolloutPlayer(rollout, None, None, play=True)  # no owner: nothing ticks it but this test
    period = rollout.dt
    t0 = time.monotonic() + 1000.0  # long after play(): the first tick is late
    rp.tick(t0)
    rp.tick(t0)
    rp.tick(t0)
    assert 1 <= rollout.steps <= 3, f"{rollout.steps} steps to catch up a stall"  # not 30000
    start = rollout.steps
    for k in range(120):  # 30 control periods, ticked between period boundaries
        rp.tick(t0 + (k + 0.5) * period / 4)
    assert 29 <= rollout.steps - start <= 31, f"{rollout.steps - start} steps in 30 periods"
    rp.configure(speed=2.0)
    start, t1 = rollout.steps, t0 + 30 * period
    for k in range(120):
        rp.tick(t1 + (k + 0.5) * period / 4)
    assert 59 <= rollout.steps - start <= 61, f"{rollout.steps - start} steps in 30 periods at 2x"
    rp.pause()
    steps = rollout.steps
    rp.tick(t1 + 1000.0)
    assert rollout.steps == steps


def test_player_pauses_steps_and_scrubs(rollout: Rollout) -> None:
    owner = SceneThread()
    rp = played(rollout, owner)
    try:
        wait_for(lambda: rollout.steps >= 25, 60, "25 steps played")
        rp.pause()
        steps = rollout.steps
        time.sleep(0.3)  # a paused player's thread goes on ticking: it must not step
        assert rollout.steps == steps
        s = rp.snapshot()
        assert s["mode"] == "rollout" and s["rollout"]["live"] and s["frame"] == s["num_frames"] - 1
        assert set(s["rollout"]["latest"]["reward_terms"]) == TERMS  # the frame shown may start an episode

        rp.step(1)  # at the live end: one more simulated step
        assert rollout.steps == steps + 1
        rp.seek(frame=10)  # back in history: shown, not simulated
        s = rp.snapshot()
        assert s["frame"] == 10 and not s["rollout"]["live"] and rollout.steps == steps + 1
        shown = s["rollout"]["shown"]["step"]
        rp.step(1)
        assert rp.snapshot()["rollout"]["shown"]["step"] == shown + 1 and rollout.steps == steps + 1
        rp.step(-3)
        assert rp.snapshot()["frame"] == 8
        rp.seek(time_s=rollout.history[-1].step * rollout.dt)
        assert rp.snapshot()["rollout"]["live"]
        rows = rp.history_rows(since_step=steps - 5)
        assert [r["step"] for r in rows] == sorted(r["step"] for r in rows) and rows[-1]["step"] == steps + 1
        assert all(set(r["terms"]) == TERMS for r in rows)

        rp.seek(frame=3)
        rp.play()  # play goes back to the live end and simulates on
        wait_for(lambda: rollout.steps > steps + 5, 5, "the rollout to go on")
        assert rp.snapshot()["rollout"]["live"]
    finally:
        rp.close()
        owner.close()


def test_the_published_feed_carries_the_state_and_the_rows(rollout: Rollout) -> None:
    """What a reader gets without a scene command: the state and the newest rows, versioned; rows stay
    in it after the history (2 s here) has forgotten them, and a change adds only its own rows."""
    owner = SceneThread()
    rp = played(rollout, owner)
    try:
        wait_for(lambda: rollout.steps >= 90, 60, "90 steps played")
        rp.pause()
        feed = rp.feed()
        assert feed is not None and feed.state == rp.snapshot()
        in_history = rp.history_rows()
        steps = [r["step"] for r in feed.rows]
        assert steps == sorted(set(steps)) and steps[0] == 1 and len(feed.rows) > len(in_history)
        assert feed.rows[-len(in_history) :] == tuple(in_history)
        rp.step(1)
        after = rp.feed()
        assert after.version > feed.version and after.rows[:-1] == feed.rows
        assert after.rows[-1]["step"] == rollout.steps and after.state["rollout"]["step"] == rollout.steps
    finally:
        rp.close()
        owner.close()


def test_newer_checkpoint_is_reloaded(tmp_path: Path, ckpt: Path, other_obs_ckpt: Path) -> None:
    run = tmp_path / "run"
    shutil.copytree(ckpt.parent, run)
    owner = SceneThread()
    rp = played(Rollout(source_for_checkpoint(run / "model.pt")), owner)
    try:
        weight = rp.rollout.agent.state_dict()["_model._action_dist._mean_net.weight"].clone()
        state = torch.load(run / "model.pt", weights_only=True)
        state["_model._action_dist._mean_net.weight"] += 0.5
        torch.save(state, run / ".model.pt.tmp")
        os.replace(run / ".model.pt.tmp", run / "model.pt")  # as the trainer writes it: atomically
        wait_for(lambda: rp.rollout.reloads == 1, 5, "the newer checkpoint to be loaded")
        new = rp.rollout.agent.state_dict()["_model._action_dist._mean_net.weight"]
        assert torch.allclose(new, weight + 0.5)
        s = rp.snapshot()["rollout"]
        assert s["checkpoint_mtime"] == pytest.approx((run / "model.pt").stat().st_mtime) and s["error"] is None

        shutil.copyfile(other_obs_ckpt, run / "model.pt")  # a file that no longer fits: keep the old weights
        wait_for(lambda: rp.rollout.error, 5, "the misfit to be reported")
        assert "observation size differs" in rp.rollout.error and rp.rollout.reloads == 1
        assert torch.allclose(rp.rollout.agent.state_dict()["_model._action_dist._mean_net.weight"], weight + 0.5)
    finally:
        rp.close()
        owner.close()


def test_misfit_checkpoint_is_refused_in_one_line(ckpt: Path, other_obs_ckpt: Path) -> None:
    src = source_for_checkpoint(other_obs_ckpt, env_config=ckpt.parent / "env_config.yaml")
    with pytest.raises(MimicKitError) as e:
        Rollout(src)
    msg = str(e.value)
    assert "\n" not in msg and "does not fit" in msg and "observation size differs" in msg


def test_inspect_checkpoint(ckpt: Path, other_obs_ckpt: Path) -> None:
    info = inspect_checkpoint(ckpt)
    assert (info["agent"], info["obs_size"], info["action_size"]) == ("PPO", 464, 28)
    assert [layer["in"] for layer in info["networks"]["actor"]] == [464, 1024]
    assert info["networks"]["action_head"][-1]["out"] == 28 and info["networks"]["critic"][-1]["out"] == 1
    obs = info["normalizers"]["obs"]
    assert obs["size"] == 464 and obs["count"] == 0 and obs["mean_std"] == pytest.approx(1.0)
    assert info["train_state"]["iteration"] == 0 and info["train_state"]["samples_per_iteration"] is None
    assert set(info["configs_beside"]) == {"env_config.yaml", "agent_config.yaml", "engine_config.yaml"}

    fit = check_fit_env(ckpt, ENV_YAML, ENGINE_YAML, None, "demo env")
    assert fit["fits"] and (fit["obs_size"], fit["action_size"]) == (464, 28)
    misfit = check_fit_env(other_obs_ckpt, ENV_YAML, ENGINE_YAML, None, "demo env")
    assert not misfit["fits"]
    assert misfit["message"].startswith("the checkpoint does not fit demo env: it was trained on observations of")
    assert check_fit_char(ckpt, PROJECT_HUMANOID, "humanoid")["fits"]


def test_agent_type_from_keys() -> None:
    t = torch.zeros(1)
    base = {"_model._actor_layers.0.weight": t, "_model._critic_layers.0.weight": t}
    assert agent_type(base)[0] == "PPO or AWR"
    assert agent_type({**base, "_model._disc_layers.0.weight": t})[0] == "AMP or ADD"
    assert agent_type({**base, "_model._enc_layers.0.weight": t, "_model._disc_layers.0.weight": t})[0] == "ASE"
    assert agent_type({**base, "_prior_model.dmodel.proj_in.weight": t})[0] == "SMP"
    assert agent_type({**base, "_train_state": {"agent_name": "AWR"}})[0] == "AWR"
    assert fit_message((464, 28), (464, 12), "go2") == (
        "the checkpoint does not fit go2: it was trained on actions of 28 values, go2 takes 12 (a different character?)"
    )
    assert fit_message((464, 28), (464, 28), "x") is None
