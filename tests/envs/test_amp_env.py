"""The AMP env on the real MuJoCo engine: disc obs size and layout, history, demos, done, reward terms."""

from __future__ import annotations

import dataclasses

import torch

from mimickit.anim.motion import LoopMode, load_motion, save_motion
from mimickit.envs.amp_env import AMPEnv
from mimickit.envs.base_env import DoneFlags
from mimickit.envs.deepmimic_env import DeepMimicEnv
from mimickit.envs.env_builder import build_env, load_env_configs
from mimickit.envs.env_config import DeepMimicEnvConfig
from mimickit.util.paths import PROJECT_DATA_DIR

ENGINE = PROJECT_DATA_DIR / "engines/mujoco_engine.yaml"
AMP = PROJECT_DATA_DIR / "envs/amp_humanoid_env.yaml"
DEMO_CLIP = PROJECT_DATA_DIR / "motions/humanoid_demo_squat.pkl"
STEP = 142  # humanoid disc obs per history step: 3 + 6 + 14·6 + 5·3 + 3 + 3 + 28


def make(num_envs: int = 4, **overrides) -> AMPEnv:
    env_cfg, engine_cfg = load_env_configs(AMP, ENGINE)
    return AMPEnv(env_cfg.model_copy(update=overrides), engine_cfg, num_envs)


def char_obs_parts(obs: torch.Tensor) -> dict[str, torch.Tensor]:
    """The humanoid's global char obs [N, 140] cut into named parts, in the reference's order."""
    return {
        "height": obs[:, 0:1], "root_rot": obs[:, 1:7], "root_vel": obs[:, 7:10], "root_ang_vel": obs[:, 10:13],
        "joint_rot": obs[:, 13:97], "dof_vel": obs[:, 97:125], "key_pos": obs[:, 125:140],
    }  # fmt: skip


def disc_step_parts(disc_obs: torch.Tensor, step: int) -> dict[str, torch.Tensor]:
    """History step `step` (0 = oldest) of the humanoid's disc obs [N, 1420] cut into named parts."""
    s = disc_obs.view(disc_obs.shape[0], 10, STEP)[:, step]
    return {
        "root_pos": s[:, 0:3], "root_rot": s[:, 3:9], "joint_rot": s[:, 9:93], "key_pos": s[:, 93:108],
        "root_vel": s[:, 108:111], "root_ang_vel": s[:, 111:114], "dof_vel": s[:, 114:142],
    }  # fmt: skip


def test_disc_obs_size_is_1420_and_info_holds_the_buffer():
    env = build_env(AMP, ENGINE, 4)
    assert isinstance(env, AMPEnv)
    assert env.get_obs_space().shape == (140,) and env.get_action_space().shape == (28,)  # MIMICKIT_SPEC.md §5.2
    # §5.4: (root pos 3 + root rot 6 + 14 joints × 6 + 5 key bodies × 3 + root vel 3 + ang vel 3 + DoF vel 28)
    # = 142 per step × 10 steps (the yaml's num_disc_obs_steps) = 1420.
    assert env.get_disc_obs_space().shape == (1420,) and env.get_num_disc_obs_steps() == 10
    _, info = env.reset()
    assert info["disc_obs"].shape == (4, 1420)
    assert set(info["reward_terms"]) == {"task"} and env.reward_weights == {"task": 1.0}
    before = info["disc_obs"].clone()
    _, reward, _, info2 = env.step(torch.zeros(4, 28))
    assert info2["disc_obs"] is info["disc_obs"] and not torch.equal(before, info2["disc_obs"])
    assert torch.equal(reward, torch.zeros(4)), "plain AMP has no task reward; the agent makes the reward"
    assert make(2, disc_dof_vel_obs=False).get_disc_obs_space().shape == (1420 - 10 * 28,)


def test_reset_history_is_the_clip_and_its_newest_step_is_the_live_state():
    env = make(4)
    obs, info = env.reset()  # the character is placed exactly on the clip at the reset time
    live, newest = char_obs_parts(obs), disc_step_parts(info["disc_obs"], 9)
    torch.testing.assert_close(newest["root_pos"][:, :2], torch.zeros(4, 2))
    for name in ("root_rot", "joint_rot", "key_pos", "root_ang_vel", "dof_vel"):
        torch.testing.assert_close(newest[name], live[name], atol=2e-3, rtol=0, msg=name)
    torch.testing.assert_close(newest["root_pos"][:, 2:], live["height"], atol=1e-4, rtol=0)
    # Older steps are earlier clip frames, not copies of the reset state.
    assert (disc_step_parts(info["disc_obs"], 0)["joint_rot"] - newest["joint_rot"]).abs().max() > 1e-3


def test_a_step_shifts_the_history_and_appends_the_live_state():
    env = make(4)
    _, info = env.reset()
    before = info["disc_obs"].clone()
    obs, _, done, info = env.step(torch.zeros(4, 28))
    assert (done == DoneFlags.NULL).all()
    for k in range(9):
        old, new = disc_step_parts(before, k + 1), disc_step_parts(info["disc_obs"], k)
        # Global obs: rotations and velocities do not depend on the (moved) newest root.
        for name in ("root_rot", "joint_rot", "key_pos", "root_vel", "root_ang_vel", "dof_vel"):
            torch.testing.assert_close(new[name], old[name], msg=f"step {k} {name}")
    live, newest = char_obs_parts(obs), disc_step_parts(info["disc_obs"], 9)
    for name in ("root_rot", "joint_rot", "key_pos", "root_vel", "root_ang_vel", "dof_vel"):
        torch.testing.assert_close(newest[name], live[name], msg=name)
    root_xy = env.engine.get_root_pos(env.get_char_id())[:, :2]
    for k in range(10):  # positions are relative to the newest root
        hist_xy = env.get_disc_history()["root_pos"][:, k, :2]
        torch.testing.assert_close(disc_step_parts(info["disc_obs"], k)["root_pos"][:, :2], hist_xy - root_xy)


def test_demo_disc_obs_are_the_reset_history_of_the_same_clip_time():
    env = make(3, rand_reset=False)  # every reset and every demo sample starts at t = 0 of the one clip
    _, info = env.reset()
    demo = env.fetch_disc_obs_demo(5)
    assert demo.shape == (5, 1420) and torch.isfinite(demo).all()
    torch.testing.assert_close(demo, info["disc_obs"][:1].expand(5, -1))
    random_demo = make(1).fetch_disc_obs_demo(64)
    assert random_demo.std(0).max() > 0.1, "with rand_reset the demo times are spread over the clip"


def test_the_end_of_a_clamped_clip_is_no_success(tmp_path):
    clip = tmp_path / "squat_clamp.pkl"
    save_motion(clip, dataclasses.replace(load_motion(DEMO_CLIP), loop_mode=LoopMode.CLAMP))
    overrides = {"motion_file": str(clip), "rand_reset": False, "enable_early_termination": False}
    amp = make(1, **overrides)
    env_cfg, engine_cfg = load_env_configs(AMP, ENGINE)
    fields = {k: getattr(env_cfg, k) for k in DeepMimicEnvConfig.model_fields}
    deepmimic = DeepMimicEnv(DeepMimicEnvConfig(**dict(fields, env_name="deepmimic", **overrides)), engine_cfg, 1)
    clip_steps = round(amp.motion_lib.get_total_length() * 30)
    flags = {"amp": [], "deepmimic": []}
    for name, env in (("amp", amp), ("deepmimic", deepmimic)):
        env.reset()
        for _ in range(clip_steps + 2):
            flags[name].append(int(env.step(torch.zeros(1, 28))[2][0]))
    assert DoneFlags.SUCC in flags["deepmimic"], "the clip end is reached"
    assert set(flags["amp"]) == {DoneFlags.NULL}


def test_an_attached_disc_reward_fills_the_reward_terms():
    env = make(4)
    env.set_disc_reward_fn(lambda disc_obs: disc_obs[:, :3].sum(-1), task_weight=0.0, disc_weight=1.0)
    assert env.reward_weights == {"task": 0.0, "disc": 1.0}
    _, info = env.reset()
    torch.testing.assert_close(info["reward_terms"]["disc"], info["disc_obs"][:, :3].sum(-1))
    _, reward, _, info = env.step(torch.zeros(4, 28))
    torch.testing.assert_close(info["reward_terms"]["disc"], info["disc_obs"][:, :3].sum(-1))
    assert torch.equal(info["reward_terms"]["task"], torch.zeros(4)) and torch.equal(reward, torch.zeros(4))
    env.set_disc_reward_fn(None)
    _, _, _, info = env.step(torch.zeros(4, 28))
    assert set(info["reward_terms"]) == {"task"}
