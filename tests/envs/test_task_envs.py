"""The AMP task envs (task_location, task_steering) on the real MuJoCo engine: task obs, task rewards by
hand, target re-sampling, markers, the reached-target diagnostic, and a short `mimickit train` / `test`."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch

from mimickit.envs.amp_env import AMPEnv
from mimickit.envs.base_env import DoneFlags
from mimickit.envs.env_builder import build_env_from_configs, load_env_configs
from mimickit.envs.env_config import TaskLocationEnvConfig, TaskSteeringEnvConfig
from mimickit.envs.task_env import AMPTaskEnv, heading_dir
from mimickit.envs.task_location_env import TaskLocationEnv, location_reward
from mimickit.envs.task_steering_env import TaskSteeringEnv, steering_reward
from mimickit.util import torch_util as tu
from mimickit.util.paths import PROJECT_DATA_DIR, PROJECT_ROOT
from tests.test_cli_train import metrics, mimickit

ENGINE = PROJECT_DATA_DIR / "engines/mujoco_engine.yaml"
LOCATION = PROJECT_DATA_DIR / "envs/amp_location_humanoid_env.yaml"
STEERING = PROJECT_DATA_DIR / "envs/amp_steering_humanoid_env.yaml"
DEMO_CLIP = PROJECT_DATA_DIR / "motions/humanoid_demo_squat.pkl"
ZERO = torch.zeros(1, 28)


def make(env_file: Path, num_envs: int = 2, visualize: bool = False, **overrides) -> AMPTaskEnv:
    """The shipped task yaml with the project's demo clip (the locomotion clips need --data_dir)."""
    env_cfg, engine_cfg = load_env_configs(env_file, ENGINE)
    env_cfg = env_cfg.model_copy(update={"motion_file": str(DEMO_CLIP), **overrides})
    env = build_env_from_configs(env_cfg, engine_cfg, num_envs, visualize=visualize)
    assert isinstance(env, AMPTaskEnv)
    return env


def root_state(env: AMPTaskEnv) -> tuple[torch.Tensor, torch.Tensor]:
    e = env.engine
    return e.get_root_pos(env.get_char_id()).clone(), e.get_root_rot(env.get_char_id()).clone()


def test_configs_builder_and_task_obs_sizes():
    loc_cfg, _ = load_env_configs(LOCATION, ENGINE)
    steer_cfg, _ = load_env_configs(STEERING, ENGINE)
    assert isinstance(loc_cfg, TaskLocationEnvConfig) and isinstance(steer_cfg, TaskSteeringEnvConfig)
    # The values written in data/envs/amp_location_humanoid_env.yaml and amp_steering_humanoid_env.yaml.
    assert (loc_cfg.episode_length, loc_cfg.tar_speed, loc_cfg.tar_dist_max) == (20.0, 1.0, 10.0)
    assert (steer_cfg.tar_speed_min, steer_cfg.tar_speed_max, steer_cfg.rand_face_dir) == (0.5, 5.0, False)
    loc, steer = make(LOCATION), make(STEERING)
    assert isinstance(loc, TaskLocationEnv) and isinstance(steer, TaskSteeringEnv)
    assert isinstance(loc, AMPEnv), "task envs are AMP envs: same disc obs"
    # The AMP humanoid obs (140) + 2 (target xy) / + 5 (direction, speed, facing).
    assert loc.get_obs_space().shape == (142,) and steer.get_obs_space().shape == (145,)
    assert loc.get_disc_obs_space().shape == (1420,) and steer.get_disc_obs_space().shape == (1420,)  # as AMP's
    obs, info = loc.reset()
    assert obs.shape == (2, 142) and set(info["reward_terms"]) == {"task"}


def test_location_obs_is_the_target_in_the_heading_frame():
    env = make(LOCATION, 3)
    obs, _ = env.reset()
    pos, rot = root_state(env)
    h = tu.calc_heading(rot)
    delta = env.get_tar_pos()[:, :2] - pos[:, :2]
    # Rotate the world offset by −heading by hand.
    x = torch.cos(h) * delta[:, 0] + torch.sin(h) * delta[:, 1]
    y = -torch.sin(h) * delta[:, 0] + torch.cos(h) * delta[:, 1]
    torch.testing.assert_close(obs[:, -2:], torch.stack([x, y], -1), atol=1e-5, rtol=0)
    dist = delta.norm(dim=-1)
    assert (dist <= 10.0 + 1e-4).all() and torch.equal(env.get_tar_pos()[:, 2], torch.zeros(3))


def test_location_reward_by_hand():
    cfg, _ = load_env_configs(LOCATION, ENGINE)
    assert isinstance(cfg, TaskLocationEnvConfig)
    origin, east = torch.zeros(1, 3), torch.tensor([[1.0, 0.0]])

    def r(tar: list[float], vel: list[float], facing: torch.Tensor) -> float:
        return float(location_reward(origin, torch.tensor([vel]), facing, torch.tensor([tar]), cfg)[0])

    assert r([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], -east) == pytest.approx(1.0), "at the target: every term is 1"
    assert r([10.0, 0.0, 0.0], [0.0, 0.0, 0.0], -east) == pytest.approx(0.5 * math.exp(-50)), "far, still, away"
    # Far, walking at the target speed straight at it and facing it: velocity and facing terms only.
    assert r([10.0, 0.0, 0.0], [1.0, 0.0, 0.0], east) == pytest.approx(0.4 + 0.1, abs=1e-6)
    # Half the target speed: exp(−4·0.5²); facing 60° off: cos 60° = 0.5.
    facing60 = torch.tensor([[0.5, math.sqrt(3) / 2]])
    expect = 0.5 * math.exp(-0.5 * 4.0) + 0.4 * math.exp(-1.0) + 0.1 * 0.5
    assert r([2.0, 0.0, 0.0], [0.5, 0.0, 0.0], facing60) == pytest.approx(expect, rel=1e-5)
    assert r([2.0, 0.0, 0.0], [-1.0, 0.0, 0.0], east) == pytest.approx(0.5 * math.exp(-2.0) + 0.1), "moving away"


def test_the_env_reward_uses_the_root_motion_over_the_step():
    env = make(LOCATION, 2)
    env.reset()
    env.get_tar_pos()[:, :2] = root_state(env)[0][:, :2] + torch.tensor([3.0, -1.0])
    before = root_state(env)[0]
    _, reward, _, info = env.step(torch.zeros(2, 28))
    pos, rot = root_state(env)
    dt = env.engine.get_timestep()
    expect = location_reward(pos, (pos - before) / dt, heading_dir(rot), env.get_tar_pos(), env.config)
    torch.testing.assert_close(info["reward_terms"]["task"], expect)
    torch.testing.assert_close(reward, expect)


def test_steering_reward_by_hand():
    cfg, _ = load_env_configs(STEERING, ENGINE)
    assert isinstance(cfg, TaskSteeringEnvConfig)
    d, speed = torch.tensor([[0.0, 1.0]]), torch.tensor([2.0])

    def r(vel: list[float], facing: torch.Tensor, face_dir: torch.Tensor = d) -> float:
        return float(steering_reward(torch.tensor([vel]), facing, d, speed, face_dir, cfg)[0])

    assert r([0.0, 2.0, 0.3], d) == pytest.approx(1.0), "exact velocity (z ignored), facing the face direction"
    assert r([0.0, -2.0, 0.0], -d) == 0.0, "against the direction and facing away"
    assert r([0.0, 0.0, 0.0], d) == pytest.approx(0.7 * math.exp(-0.5 * 4.0) + 0.3)
    sideways = torch.tensor([[1.0, 0.0]])
    assert r([1.0, 2.0, 0.0], sideways) == pytest.approx(0.7 * math.exp(-0.5)), "facing 90° off scores 0"


def test_steering_obs_holds_direction_speed_and_facing_in_the_heading_frame():
    env = make(STEERING, 3, rand_face_dir=True)
    obs, _ = env.reset()
    t = env.get_targets()
    _, rot = root_state(env)
    h = tu.calc_heading(rot)
    tar_angle = torch.atan2(t["tar_dir"][:, 1], t["tar_dir"][:, 0])
    face_angle = torch.atan2(t["face_dir"][:, 1], t["face_dir"][:, 0])
    local = torch.stack([torch.cos(tar_angle - h), torch.sin(tar_angle - h)], -1)
    torch.testing.assert_close(obs[:, -5:-3], local, atol=1e-5, rtol=0)
    torch.testing.assert_close(obs[:, -3], t["tar_speed"])
    torch.testing.assert_close(obs[:, -2:], torch.stack([torch.cos(face_angle - h), torch.sin(face_angle - h)], -1),
                               atol=1e-5, rtol=0)  # fmt: skip
    assert ((t["tar_speed"] >= 0.5) & (t["tar_speed"] <= 5.0)).all()
    same = make(STEERING, 3)  # the humanoid yaml: rand_face_dir False, face where you go
    same.reset()
    torch.testing.assert_close(same.get_targets()["face_dir"], same.get_targets()["tar_dir"])


@pytest.mark.parametrize("env_file", [LOCATION, STEERING])
def test_targets_change_on_schedule_and_on_reset(env_file: Path):
    # 0.5 s between changes = 15 control steps at 30 Hz; no early termination to keep every env running.
    env = make(env_file, 2, tar_change_time_min=0.5, tar_change_time_max=0.5, enable_early_termination=False)
    env.reset()

    def targets() -> torch.Tensor:
        if isinstance(env, TaskLocationEnv):
            return env.get_tar_pos()[:, :2].clone()
        return env.get_targets()["tar_dir"].clone()

    first = targets()
    for _ in range(14):
        env.step(torch.zeros(2, 28))
    torch.testing.assert_close(targets(), first, msg="no change before 0.5 s")
    env.step(torch.zeros(2, 28))  # t = 0.5 s
    changed = targets()
    assert (changed - first).norm(dim=-1).min() > 1e-3, "both envs got new targets at 0.5 s"
    torch.testing.assert_close(env.get_target_change_time(), torch.full((2,), 1.0))
    env.reset(torch.tensor([1]))
    after_reset = targets()
    torch.testing.assert_close(after_reset[0], changed[0])
    assert (after_reset[1] - changed[1]).norm() > 1e-3, "a reset env gets a new target"
    torch.testing.assert_close(env.get_target_change_time(), torch.tensor([1.0, 0.5]))


@pytest.mark.parametrize("env_file", [LOCATION, STEERING])
def test_markers_exist_only_with_visualize_and_show_the_target(env_file: Path):
    plain = make(env_file, 2)
    assert not plain.has_markers()
    env = make(env_file, 2, visualize=True)
    assert env.has_markers()
    env.reset()
    for _ in range(3):
        env.step(torch.zeros(2, 28))
    marker = env.engine.get_root_pos(env.get_marker_id())
    if isinstance(env, TaskLocationEnv):
        torch.testing.assert_close(marker, env.get_tar_pos(), atol=1e-4, rtol=0)
    else:
        root = root_state(env)[0]
        torch.testing.assert_close(marker[:, :2], root[:, :2] + env.get_targets()["tar_dir"], atol=1e-4, rtol=0)
    # The markers are visual only: the character's physics is the same with and without them.
    torch.manual_seed(0)
    a = make(env_file, 1)
    a.reset()
    torch.manual_seed(0)
    b = make(env_file, 1, visualize=True, visualize_ref_char=False)
    b.reset()
    for _ in range(10):
        oa, *_ = a.step(ZERO)
        ob, *_ = b.step(ZERO)
    torch.testing.assert_close(oa, ob, atol=1e-5, rtol=0)


def test_reached_target_diagnostic_counts_finished_episodes():
    # 0.2 s episodes (6 steps); targets fixed for longer than that.
    env = make(LOCATION, 2, episode_length=0.2, tar_dist_min=8.0, enable_early_termination=False)
    assert env.record_diagnostics() == {"tar_episodes": 0.0, "tar_reached_frac": 0.0}
    env.reset()
    env.get_tar_pos()[0, :2] = root_state(env)[0][0, :2]  # env 0 stands on its target; env 1's is ≥ 8 m away
    done = torch.zeros(2, dtype=torch.long)
    steps = 0
    while (done == DoneFlags.NULL).all():
        _, _, done, _ = env.step(torch.zeros(2, 28))
        steps += 1
    assert steps == 6 and (done == DoneFlags.TIME).all()
    assert env.record_diagnostics() == {"tar_episodes": 2.0, "tar_reached_frac": 0.5}
    assert env.record_diagnostics()["tar_episodes"] == 0.0, "each call reports the episodes since the last"


@pytest.mark.integration
def test_location_train_and_test_in_fresh_processes(tmp_path: Path, test_data: Path) -> None:
    out = tmp_path / "run"
    common = ["--arg_file", str(PROJECT_ROOT / "args/amp_location_humanoid_args.txt"), "--data_dir", str(test_data)]
    r = mimickit("train", *common, "--num_envs", "4", "--max_samples", "256", "--out_dir", str(out), "--rand_seed", "0")
    assert r.returncode == 0, r.stderr[-3000:]
    for name in ("log.txt", "metrics.jsonl", "model.pt", "env_config.yaml", "agent_config.yaml"):
        assert (out / name).is_file(), name
    assert "task_location" in (out / "env_config.yaml").read_text()
    rows = metrics(out)
    assert [m["samples"] for m in rows] == [128, 256]
    for row in rows:
        assert row["reward_terms.task"] > 0.0, "the location reward is positive (position term)"
        assert row["reward_terms.disc"] is not None and "tar_reached_frac" in row and "tar_episodes" in row
    state = torch.load(out / "model.pt", weights_only=True)
    assert state["_obs_norm._mean"].shape == (142,)

    r = mimickit("test", *common, "--num_envs", "2", "--model_file", str(out / "model.pt"), "--test_episodes", "2",
                 "--json")  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    result = json.loads(r.stdout.strip().splitlines()[-1])
    assert result["episodes"] >= 2 and 0 < result["mean_episode_length"] <= 600
    assert result["mean_return"] > 0.0, "the task env's own reward is the location reward"
