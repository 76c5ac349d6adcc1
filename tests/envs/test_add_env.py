"""The ADD env on the real MuJoCo engine (the project's humanoid and demo clip, so no reference data is
needed): disc obs size and layout for agent and reference, the features by hand on small tensors,
DeepMimic's done and tracking errors, and the disc reward fed the difference."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import torch

from mimickit.anim.motion import LoopMode, load_motion, save_motion
from mimickit.envs.add_env import ADDEnv, compute_add_disc_obs
from mimickit.envs.base_env import DoneFlags, EnvMode
from mimickit.envs.env_builder import build_env, load_env_configs
from mimickit.util import torch_util as tu
from mimickit.util.paths import PROJECT_DATA_DIR

ENGINE = PROJECT_DATA_DIR / "engines/mujoco_engine.yaml"
ADD = PROJECT_DATA_DIR / "envs/add_humanoid_env.yaml"
DEMO_CLIP = PROJECT_DATA_DIR / "motions/humanoid_demo_squat.pkl"
TRACKING = {"root_pos_err", "root_rot_err", "body_pos_err", "body_rot_err", "dof_vel_err", "root_vel_err",
            "root_ang_vel_err", "paper_pos_err_m", "paper_dof_vel_err"}  # fmt: skip


def make(num_envs: int = 4, **overrides) -> ADDEnv:
    env_cfg, engine_cfg = load_env_configs(ADD, ENGINE)
    update = {"motion_file": str(DEMO_CLIP), **overrides}
    return ADDEnv(env_cfg.model_copy(update=update), engine_cfg, num_envs)


def disc_parts(disc_obs: torch.Tensor) -> dict[str, torch.Tensor]:
    """The humanoid's ADD disc obs [N, 172] cut into named parts, in the reference's order."""
    d = disc_obs
    return {
        "root_pos": d[:, 0:3], "root_rot": d[:, 3:9], "joint_rot": d[:, 9:93], "body_pos": d[:, 93:138],
        "root_vel": d[:, 138:141], "root_ang_vel": d[:, 141:144], "dof_vel": d[:, 144:172],
    }  # fmt: skip


def expected_parts(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Global ADD features assembled directly from a state (root_pos, root_rot, joint_rot, body_pos, ...)."""
    return {
        "root_pos": state["root_pos"],
        "root_rot": tu.quat_to_tan_norm(state["root_rot"]),
        "joint_rot": tu.quat_to_tan_norm(state["joint_rot"]).flatten(-2),
        "body_pos": (state["body_pos"] - state["root_pos"].unsqueeze(-2)).flatten(-2),
        "root_vel": state["root_vel"],
        "root_ang_vel": state["root_ang_vel"],
        "dof_vel": state["dof_vel"],
    }


def test_build_env_from_the_yaml_sizes(tmp_path: Path):
    yaml = tmp_path / "add.yaml"
    yaml.write_text(ADD.read_text().replace("data/motions/humanoid/humanoid_walk.pkl", str(DEMO_CLIP)))
    env = build_env(yaml, ENGINE, 3)
    assert isinstance(env, ADDEnv)
    assert env.get_obs_space().shape == (464,) and env.get_action_space().shape == (28,)  # MIMICKIT_SPEC.md §5.3
    # §5.6: root pos 3 + root rot 6 + 14 joints × 6 + 15 bodies × 3 + root vel 3 + ang vel 3 + DoF vel 28 = 172.
    assert env.get_disc_obs_space().shape == (172,) and env.get_num_disc_obs_steps() == 1
    _, info = env.reset()
    assert info["disc_obs"].shape == (3, 172) and info["disc_obs_demo"].shape == (3, 172)
    assert info["disc_obs_demo"] is env.get_disc_obs_demo()
    assert set(info["reward_terms"]) == {"task"}
    _, _, _, info = env.step(torch.zeros(3, 28))  # a training reset leaves tracking to the steps
    assert set(info["tracking"]) == TRACKING
    assert make(2, disc_dof_vel_obs=False).get_disc_obs_space().shape == (172 - 28,)
    assert make(2, num_disc_obs_steps=3).get_disc_obs_space().shape == (3 * 172,)


def test_features_by_hand_global_and_local():
    # One step, one joint, two bodies, one DoF. Root at (1, 2, 0.9) turned 90° about z.
    yaw = tu.quat_from_axis_angle(torch.tensor([0.0, 0.0, 1.0]), torch.tensor(math.pi / 2))
    hist = {
        "root_pos": torch.tensor([[[1.0, 2.0, 0.9]]]),
        "root_rot": yaw.view(1, 1, 4),
        "root_vel": torch.tensor([[[0.0, 1.0, 0.0]]]),
        "root_ang_vel": torch.tensor([[[0.0, 0.0, 2.0]]]),
        "joint_rot": tu.quat_identity((1, 1, 1)),
        "dof_vel": torch.tensor([[[5.0]]]),
        "body_pos": torch.tensor([[[[1.0, 2.0, 0.9], [1.0, 3.0, 0.9]]]]),
    }
    identity_tan_norm = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0]  # x axis, z axis of the identity rotation
    yaw_tan_norm = [0.0, 1.0, 0.0, 0.0, 0.0, 1.0]  # x axis turned onto y
    glob = compute_add_disc_obs(hist, global_obs=True, dof_vel_obs=True)
    expected = [1.0, 2.0, 0.9, *yaw_tan_norm, *identity_tan_norm, 0, 0, 0, 0, 1, 0, 0, 1, 0, 0, 0, 2, 5]
    torch.testing.assert_close(glob, torch.tensor([expected]), atol=1e-6, rtol=0)
    # Local: root xy dropped, everything in the root's heading frame (turned back by 90°): +y becomes +x.
    loc = compute_add_disc_obs(hist, global_obs=False, dof_vel_obs=False)
    expected = [0.0, 0.0, 0.9, *identity_tan_norm, *identity_tan_norm, 0, 0, 0, 1, 0, 0, 1, 0, 0, 0, 0, 2]
    torch.testing.assert_close(loc, torch.tensor([expected]), atol=1e-6, rtol=0)
    # Two history steps: each step in its own frame, oldest first.
    two = {k: torch.cat([v, v], dim=1) for k, v in hist.items()}
    two["root_pos"] = torch.tensor([[[0.0, 0.0, 0.5], [1.0, 2.0, 0.9]]])
    out = compute_add_disc_obs(two, global_obs=False, dof_vel_obs=False).view(2, -1)
    assert out[0, 2].item() == 0.5 and torch.equal(out[1], loc[0])


def test_agent_features_are_the_live_state_and_demo_features_the_reference():
    env = make(4)
    _, info = env.reset()  # on the clip: the two agree exactly
    torch.testing.assert_close(info["disc_obs"], info["disc_obs_demo"])
    for _ in range(5):
        _, _, done, info = env.step(torch.zeros(4, 28))
    assert (done == DoneFlags.NULL).all()
    e, c = env.engine, env.get_char_id()
    live = {
        "root_pos": e.get_root_pos(c), "root_rot": e.get_root_rot(c), "root_vel": e.get_root_vel(c),
        "root_ang_vel": e.get_root_ang_vel(c), "joint_rot": env.char_model.dof_to_rot(e.get_dof_pos(c)),
        "dof_vel": e.get_dof_vel(c), "body_pos": e.get_body_pos(c),
    }  # fmt: skip
    lib = env.motion_lib
    f = lib.calc_motion_frame(env.get_motion_ids(), env.get_motion_time())
    body_pos, _ = env.char_model.forward_kinematics(f.root_pos, f.root_rot, f.joint_rot)
    ref = {
        "root_pos": f.root_pos, "root_rot": f.root_rot, "root_vel": f.root_vel, "root_ang_vel": f.root_ang_vel,
        "joint_rot": f.joint_rot, "dof_vel": f.dof_vel, "body_pos": body_pos,
    }  # fmt: skip
    for name, (got, want) in {"agent": (info["disc_obs"], live), "demo": (info["disc_obs_demo"], ref)}.items():
        parts, exp = disc_parts(got), expected_parts(want)
        for k in parts:
            torch.testing.assert_close(parts[k], exp[k], atol=1e-4, rtol=0, msg=f"{name} {k}")
    diff = info["disc_obs_demo"] - info["disc_obs"]
    assert diff.abs().max() > 1e-2, "a zero-action policy drifts off the clip"


def test_history_of_several_steps_ends_with_the_one_step_features():
    one, three = make(2, rand_reset=False), make(2, rand_reset=False, num_disc_obs_steps=3)
    one.reset(), three.reset()
    for _ in range(4):
        _, _, _, info1 = one.step(torch.zeros(2, 28))
        _, _, _, info3 = three.step(torch.zeros(2, 28))
    for key in ("disc_obs", "disc_obs_demo"):
        torch.testing.assert_close(info3[key][:, 2 * 172 :], info1[key], atol=1e-5, rtol=0, msg=key)
        assert not torch.allclose(info3[key][:, :172], info1[key], atol=1e-3), f"{key}: older steps differ"


def test_disc_reward_gets_the_difference_and_tracking_is_recorded_in_test_mode():
    env = make(3)
    env.set_disc_reward_fn(lambda diff: diff.abs().sum(-1), task_weight=0.0, disc_weight=1.0)
    assert env.reward_weights == {"task": 0.0, "disc": 1.0}
    env.set_mode(EnvMode.TEST)
    env.reset()
    for _ in range(3):
        _, reward, _, info = env.step(torch.zeros(3, 28))
    diff = info["disc_obs_demo"] - info["disc_obs"]
    torch.testing.assert_close(info["reward_terms"]["disc"], diff.abs().sum(-1))
    assert torch.equal(reward, torch.zeros(3)), "no task reward: the agent makes the reward"
    diag = env.record_diagnostics()
    assert set(diag) == TRACKING and diag["body_pos_err"] > 0
    assert info["tracking"]["body_pos_err"].min() > 0


def test_clip_end_is_a_success_and_pose_termination_applies(tmp_path: Path):
    clip = tmp_path / "squat_clamp.pkl"
    save_motion(clip, dataclasses.replace(load_motion(DEMO_CLIP), loop_mode=LoopMode.CLAMP))
    env = make(1, motion_file=str(clip), rand_reset=False, enable_early_termination=False)
    env.reset()
    flags = [int(env.step(torch.zeros(1, 28))[2][0]) for _ in range(round(env.motion_lib.get_total_length() * 30) + 1)]
    assert flags[-1] == DoneFlags.SUCC, "as DeepMimic (AMP has no success)"
    tight = make(2, pose_termination_dist=1e-3)  # any drift from the clip fails at once
    tight.reset()
    assert (tight.step(torch.zeros(2, 28))[2] == DoneFlags.FAIL).all()
