"""The SMP envs on the real MuJoCo engine: the GSI path (disc obs → motion frames → init states) gives back
the clip's state, a reset from a GSI buffer puts the character and its disc history in that state, the
task envs take GSI too, the dodgeball env throws balls that reach their target in dist / speed seconds and
count the hit, and config mistakes are one-line errors."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

from mimickit.envs.base_env import DoneFlags
from mimickit.envs.env_builder import ENVS, build_env_from_configs, load_env_configs
from mimickit.envs.smp_env import SMPEnv
from mimickit.envs.task_dodgeball_env import TaskDodgeballEnv, ballistic_launch, dodge_reward, dodgeball_hits
from mimickit.envs.task_env import AMPTaskEnv
from mimickit.util import torch_util as tu
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA_DIR
from tests.util.config_errors import load_error

ENGINE = PROJECT_DATA_DIR / "engines/mujoco_engine.yaml"
ENVS_DIR = PROJECT_DATA_DIR / "envs"
SMP = ENVS_DIR / "smp_humanoid_env.yaml"  # global obs
LOCATION = ENVS_DIR / "smp_location_humanoid_env.yaml"  # local obs
STEERING = ENVS_DIR / "smp_steering_humanoid_env.yaml"
DODGEBALL = ENVS_DIR / "smp_dodgeball_humanoid_env.yaml"
DEMO_CLIP = PROJECT_DATA_DIR / "motions/humanoid_demo_squat.pkl"
POSE_PER_STEP = 3 + 6 + 6 * 14 + 3 * 5  # root pos, root rot, 14 joints, 5 key bodies: before the velocities


def make(env_file: Path, num_envs: int = 2, motion_file: Path = DEMO_CLIP, **overrides) -> SMPEnv:
    env_cfg, engine_cfg = load_env_configs(env_file, ENGINE, motion_file)
    env = build_env_from_configs(env_cfg.model_copy(update=overrides), engine_cfg, num_envs)
    assert isinstance(env, SMPEnv)
    return env


def angle(q0: torch.Tensor, q1: torch.Tensor) -> torch.Tensor:
    return tu.quat_diff_angle(q0, q1)


def clip_window(env: SMPEnv, n: int = 3) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
    """n clip windows (history ending at times spread over the clip) and their disc obs [n, S·step]."""
    length = float(env.motion_lib.get_motion_length(torch.zeros(1, dtype=torch.long))[0])
    times = torch.linspace(0.4, 0.9, n) * length
    hist = env._motion_history(torch.zeros(n, dtype=torch.long), times)
    return hist, env._disc_obs_from_hist(hist)


def relative_to_newest(hist: dict[str, torch.Tensor], global_obs: bool) -> dict[str, torch.Tensor]:
    """The window as the disc obs holds it: xy relative to the newest root, heading removed when local."""
    pos, rot = hist["root_pos"], hist["root_rot"]
    rel = pos - pos[:, -1:]
    rel[..., 2] = pos[..., 2]
    if global_obs:
        return {"root_pos": rel, "root_rot": rot}
    h = tu.calc_heading_quat_inv(rot[:, -1]).unsqueeze(1).expand_as(rot)
    rel = tu.quat_rotate(h, rel)
    rel[..., 2] = pos[..., 2]
    return {"root_pos": rel, "root_rot": tu.quat_mul(h, rot)}


# ------------------------------------------------------------------------------- GSI round trip
def check_round_trip(env: SMPEnv) -> None:
    hist, disc_obs = clip_window(env)
    frames = env.disc_obs_to_motion_frames(disc_obs)
    s, d = env.get_num_disc_obs_steps(), env.char_model.get_dof_size()
    assert frames.shape == (3, s, 6 + d)
    want = relative_to_newest(hist, env.config.global_obs)
    torch.testing.assert_close(frames[..., 0:3], want["root_pos"], atol=1e-5, rtol=0)
    assert float(angle(tu.exp_map_to_quat(frames[..., 3:6]), want["root_rot"]).max()) < 1e-3
    joint_rot = env.char_model.dof_to_rot(frames[..., 6:])
    assert float(angle(joint_rot, hist["joint_rot"]).max()) < 1e-3
    # The init states: the same pose, FK bodies where the clip's key bodies are (relative to the newest root).
    states = env.motion_frames_to_init_states(frames)
    assert set(states) == {"root_pos", "root_rot", "root_vel", "root_ang_vel", "joint_rot", "dof_pos",
                           "dof_vel", "body_pos", "body_rot"}  # fmt: skip
    key = states["body_pos"][:, :, env._key_body_ids] - states["root_pos"].unsqueeze(-2)
    want_key = hist["body_pos"] - hist["root_pos"].unsqueeze(-2)
    if not env.config.global_obs:
        h = tu.calc_heading_quat_inv(hist["root_rot"][:, -1])[:, None, None].expand(*want_key.shape[:-1], 4)
        want_key = tu.quat_rotate(h, want_key)
    torch.testing.assert_close(key, want_key, atol=1e-4, rtol=0)
    # Velocities are forward differences over the control step: the clip's own, to its sampling.
    dt = env.engine.get_timestep()
    torch.testing.assert_close(states["root_vel"][:, 0], (states["root_pos"][:, 1] - states["root_pos"][:, 0]) / dt)
    torch.testing.assert_close(states["root_vel"][:, -1], states["root_vel"][:, -2])
    speed = hist["root_vel"].norm(dim=-1).mean()
    assert float((states["root_vel"].norm(dim=-1).mean() - speed).abs()) < 0.1 + 0.2 * float(speed)


@pytest.mark.parametrize("env_file", [SMP, LOCATION], ids=["global_obs", "local_obs"])
def test_disc_obs_of_a_clip_go_back_to_its_root_and_joint_state(env_file: Path) -> None:
    env = make(env_file)
    try:
        check_round_trip(env)
    finally:
        env.engine.close()


def test_round_trip_on_a_reference_clip(test_data: Path) -> None:
    """The shipped smp_humanoid_env.yaml with its own clip (MimicKit's spinkick: fast turns, large angles)."""
    env_cfg, engine_cfg = load_env_configs(SMP, ENGINE)
    clip = test_data / "motions/humanoid/humanoid_spinkick.pkl"
    env = build_env_from_configs(env_cfg.model_copy(update={"motion_file": str(clip)}), engine_cfg, 2)
    try:
        assert isinstance(env, SMPEnv)
        check_round_trip(env)
    finally:
        env.engine.close()


# ------------------------------------------------------------------------------- GSI resets
def test_a_reset_from_a_gsi_buffer_puts_the_character_in_that_state() -> None:
    env = make(SMP, num_envs=2)
    try:
        env.reset()
        assert not env.has_gsi_buffer()
        _, disc_obs = clip_window(env, n=1)
        env.init_gsi_buffer(disc_obs)
        assert env.has_gsi_buffer() and len(env.get_gsi_buffer()) == 1
        states = env.motion_frames_to_init_states(env.disc_obs_to_motion_frames(disc_obs))
        _, info = env.reset()
        e, c = env.engine, env.get_char_id()
        newest = {k: v[:, -1].expand(2, *v.shape[2:]) for k, v in states.items()}
        torch.testing.assert_close(e.get_root_pos(c), newest["root_pos"], atol=1e-5, rtol=0)
        assert float(angle(e.get_root_rot(c), newest["root_rot"]).max()) < 1e-4
        assert float(angle(e.get_joint_rot(c), newest["joint_rot"]).max()) < 1e-3
        torch.testing.assert_close(e.get_root_vel(c), newest["root_vel"], atol=1e-4, rtol=0)
        torch.testing.assert_close(e.get_dof_vel(c), newest["dof_vel"], atol=1e-4, rtol=0)
        torch.testing.assert_close(env.get_motion_time(), torch.zeros(2))
        # The disc history is the whole window: the pose part of the disc obs is the sample's again.
        s = env.get_num_disc_obs_steps()
        got = info["disc_obs"].view(2, s, -1)[..., :POSE_PER_STEP]
        want = disc_obs.view(1, s, -1)[..., :POSE_PER_STEP].expand(2, -1, -1)
        torch.testing.assert_close(got, want, atol=1e-4, rtol=0)
        # A refresh replaces the oldest state: the next resets start from the new window.
        hist2, disc_obs2 = clip_window(env, n=3)
        env.add_gsi_samples(disc_obs2[:1])
        _, info = env.reset()
        got = info["disc_obs"].view(2, s, -1)[..., :POSE_PER_STEP]
        torch.testing.assert_close(got, disc_obs2[:1].view(1, s, -1)[..., :POSE_PER_STEP].expand(2, -1, -1),
                                   atol=1e-4, rtol=0)  # fmt: skip
        obs, r, done, info = env.step(torch.zeros(2, env.get_action_space().shape[0]))
        assert bool(torch.isfinite(obs).all()) and info["disc_obs"].shape == (2, disc_obs.shape[1])
    finally:
        env.engine.close()


def test_windows_may_come_as_steps_and_the_buffer_draws_every_state() -> None:
    env = make(SMP, num_envs=4)
    try:
        _, disc_obs = clip_window(env, n=4)
        env.init_gsi_buffer(disc_obs.view(4, env.get_num_disc_obs_steps(), -1))  # [B, S, step], as the reference
        env.reset()
        root = env.engine.get_root_pos(env.get_char_id())[:, 2]
        want = env.disc_obs_to_motion_frames(disc_obs)[:, -1, 2]
        # One pass of the buffer's permutation: each of the 4 states once.
        torch.testing.assert_close(root.sort().values, want.sort().values, atol=1e-5, rtol=0)
    finally:
        env.engine.close()


@pytest.mark.parametrize("env_file", [LOCATION, STEERING], ids=["location", "steering"])
def test_the_task_envs_take_gsi_and_keep_their_task(env_file: Path) -> None:
    env = make(env_file)
    try:
        assert isinstance(env, AMPTaskEnv)
        env.reset()
        _, disc_obs = clip_window(env, n=2)
        env.init_gsi_buffer(disc_obs)
        obs, info = env.reset()
        root = env.engine.get_root_pos(env.get_char_id())
        assert float(root[:, :2].abs().max()) < 1e-5  # the newest root of a GSI window stands at the origin
        assert obs.shape == (2, env.get_obs_space().shape[0]) and set(info["reward_terms"]) == {"task"}
        env.step(torch.zeros(2, env.get_action_space().shape[0]))
        assert env.task_target(0)["kind"] in ("location", "steering")
    finally:
        env.engine.close()


# ------------------------------------------------------------------------------- config errors
@pytest.mark.parametrize(
    "override, needle",
    [
        ({"enable_tar_obs": True}, "requires enable_tar_obs False"),
        ({"pose_termination": True}, "requires pose_termination False"),
        ({"root_height_obs": False}, "requires root_height_obs True"),
    ],
)
def test_gsi_on_an_unfit_config_is_one_line(override: dict, needle: str) -> None:
    env = make(SMP, **override)
    try:
        with pytest.raises(MimicKitError, match=needle) as e:
            env.init_gsi_buffer(env.fetch_disc_obs_demo(2))
        assert "\n" not in str(e.value) and not env.has_gsi_buffer()
    finally:
        env.engine.close()


def test_gsi_samples_of_the_wrong_shape_are_one_line() -> None:
    env = make(SMP)
    try:
        with pytest.raises(MimicKitError, match=r"samples of shape \(2, 7\)") as e:
            env.init_gsi_buffer(torch.zeros(2, 7))
        assert "\n" not in str(e.value)
        with pytest.raises(MimicKitError, match="before init_gsi_buffer"):
            env.add_gsi_samples(env.fetch_disc_obs_demo(1))
        env.init_gsi_buffer(env.fetch_disc_obs_demo(2))
        with pytest.raises(MimicKitError, match="3 samples exceed the buffer's 2"):
            env.add_gsi_samples(env.fetch_disc_obs_demo(3))
    finally:
        env.engine.close()


@pytest.mark.parametrize(
    "edit, needle",
    [
        ("proj_dist_min: 8.0", "proj_dist_min: 12.0"),
        ("proj_speed_max: 15.0", "proj_speed_max: -1.0"),
        ("num_projectiles: 1", "num_projectiles: 0"),
    ],
)
def test_dodgeball_config_errors_are_one_line(tmp_path: Path, edit: str, needle: str) -> None:
    text = DODGEBALL.read_text()
    assert edit in text
    f, msg = load_error(tmp_path, text.replace(edit, needle), lambda f: load_env_configs(f, ENGINE), "env.yaml")
    assert msg.startswith(f"{f}") and "\n" not in msg
    assert needle.split(":")[0] in msg


def test_an_unknown_target_body_is_one_line() -> None:
    with pytest.raises(MimicKitError, match="no body named 'tail'") as e:
        make(DODGEBALL, num_envs=1, proj_target_body="tail")
    assert "\n" not in str(e.value)


# ------------------------------------------------------------------------------- dodgeball
def test_the_registry_lists_the_smp_envs() -> None:
    assert {"smp", "task_dodgeball"} <= set(ENVS.names)
    assert ENVS.resolve("smp") is SMPEnv and ENVS.resolve("task_dodgeball") is TaskDodgeballEnv
    for name in ("task_location", "task_steering"):
        assert issubclass(ENVS.resolve(name), SMPEnv)


def test_the_launch_reaches_the_predicted_target_after_dist_over_speed() -> None:
    n = 64
    target, target_vel = torch.randn(n, 3) + torch.tensor([0.0, 0.0, 1.0]), torch.randn(n, 3)
    speed, dist = 12 + 3 * torch.rand(n), 8 + 2 * torch.rand(n)
    height, ang = 0.5 + 2 * torch.rand(n), 2 * math.pi * torch.rand(n)
    pos, vel = ballistic_launch(target, target_vel, speed, dist, height, ang, -9.81)
    t = (dist / speed).unsqueeze(-1)
    g = torch.tensor([0.0, 0.0, -9.81])
    at_t = pos + vel * t + 0.5 * g * t**2
    torch.testing.assert_close(at_t[:, :2], (target + target_vel * t)[:, :2], atol=1e-4, rtol=0)
    torch.testing.assert_close(at_t[:, 2], target[:, 2], atol=1e-4, rtol=0)
    torch.testing.assert_close(vel[:, :2].norm(dim=-1), speed)
    torch.testing.assert_close(pos[:, 2], height)
    torch.testing.assert_close((pos[:, :2] - (target + target_vel * t)[:, :2]).norm(dim=-1), dist)


def test_a_ball_thrown_at_a_standing_character_hits_the_torso_on_time() -> None:
    """No aim noise, no automatic launches: one ball thrown at the torso right after a reset flies freely
    (the ballistic path, to the integrator's rounding) until it hits, within dist / speed seconds, and the
    hit ends the episode."""
    env = make(DODGEBALL, num_envs=1, proj_aim_noise_scale=0.0, proj_trigger_time_min=100.0,
               proj_trigger_time_max=100.0)  # fmt: skip
    try:
        assert isinstance(env, TaskDodgeballEnv)
        env.reset()
        e, c, ball = env.engine, env.get_char_id(), env.get_proj_ids()[0]
        torch.testing.assert_close(e.get_root_pos(ball)[0], torch.tensor([10.0, 10.0, 0.1]))
        hold = e.get_dof_pos(c).clone()  # PD targets at the reset pose: the character stands
        torso = env.char_model.get_body_id("torso")
        target = e.get_body_pos(c)[0, torso].clone()
        target_vel = e.get_body_vel(c)[0, torso].clone()
        env.launch_projectiles(torch.tensor([0]), torch.tensor([0]))
        p0, v0 = e.get_root_pos(ball)[0].clone(), e.get_root_vel(ball)[0].clone()
        speed = float(v0[:2].norm())
        dist = float((p0[:2] - target[:2]).norm())  # the reset pose moves slowly: prediction ≈ the torso now
        t_hit = dist / speed
        assert 12.0 <= speed <= 15.0 and 7.5 <= dist <= 10.5
        assert float(env.get_proj_trigger_times()[0, 0]) >= 100.0
        dt, g = e.get_timestep(), torch.tensor([0.0, 0.0, -9.81])
        hit_time = None
        for k in range(1, int(t_hit / dt) + 4):
            _, _, done, _ = env.step(hold)
            t = k * dt
            if bool(env.get_proj_hits()[0, 0]):
                hit_time = t
                assert int(done[0]) == int(DoneFlags.FAIL)
                break
            assert int(done[0]) == int(DoneFlags.NULL), f"episode ended at {t:.3f} s without a hit"
            free = p0 + v0 * t + 0.5 * g * t * t
            torch.testing.assert_close(e.get_root_pos(ball)[0], free, atol=0.03, rtol=0)
        assert hit_time is not None, f"no hit within {t_hit:.3f} s + 3 steps"
        # The ball's centre meets the torso's when t = dist / speed; contact comes a few cm earlier.
        assert t_hit - 0.1 <= hit_time <= t_hit + 2 * dt, (hit_time, t_hit)
        ball_pos = e.get_root_pos(ball)[0]
        assert float((e.get_body_pos(c)[0] - ball_pos).norm(dim=-1).min()) < env.config.hit_dist
        assert target_vel.norm() < 1.0
    finally:
        env.engine.close()


def test_dodgeball_obs_reward_and_hit_rule() -> None:
    env = make(DODGEBALL, num_envs=2)
    try:
        obs, info = env.reset()
        amp_dim = 140  # the AMP humanoid's obs; + 6 per ball
        assert obs.shape == (2, amp_dim + 6) and set(info["reward_terms"]) == {"task"}
        assert env.task_target(0)["kind"] == "dodgeball"
        # Reward: 0.9·(1 − e^(−0.3 d)) + 0.1·e^(−|v_xy|²).
        r = dodge_reward(torch.zeros(1, 3), torch.tensor([[1.0, 0.0, 5.0]]), torch.tensor([[[3.0, 4.0, 0.0]]]))
        torch.testing.assert_close(r, torch.tensor([0.9 * (1 - math.exp(-1.5)) + 0.1 * math.exp(-1.0)]))
        # Hits: near a body and (a contact force or a change of velocity beyond gravity's).
        body = torch.zeros(1, 2, 3)
        near, far = torch.tensor([[[0.5, 0.0, 0.0]]]), torch.tensor([[[3.0, 0.0, 0.0]]])
        free_v, prev = torch.tensor([[[10.0, 0.0, -0.327]]]), torch.tensor([[[10.0, 0.0, 0.0]]])
        bounced = torch.tensor([[[-2.0, 0.0, 0.0]]])
        no_f, f = torch.zeros(1, 1), torch.ones(1, 1)

        def hits(pos: torch.Tensor, vel: torch.Tensor, force: torch.Tensor) -> bool:
            return bool(dodgeball_hits(body, pos, vel, prev, force, 0.8, 0.1, 1.5, -9.81, 1 / 30)[0, 0])

        assert not hits(near, free_v, no_f) and hits(near, bounced, no_f) and hits(near, free_v, f)
        assert not hits(far, bounced, f)
        # Balls launch by themselves at their trigger times (no early termination: no reset comes between).
        env.engine.close()
        env = make(DODGEBALL, num_envs=1, enable_early_termination=False)
        env.reset()
        trigger = float(env.get_proj_trigger_times()[0, 0])
        assert 1.0 <= trigger <= 4.0
        ball = env.get_proj_ids()[0]
        while float(env.get_env_time()[0]) < trigger:
            assert float(env.engine.get_root_vel(ball)[0].norm()) < 0.05  # resting on the floor until then
            env.step(torch.zeros(1, env.get_action_space().shape[0]))
        assert float(env.engine.get_root_vel(ball)[0, :2].norm()) >= 12.0 - 1e-3
        assert float(env.get_proj_trigger_times()[0, 0]) >= float(env.get_env_time()[0]) + 1.0 - 1e-5
    finally:
        env.engine.close()
