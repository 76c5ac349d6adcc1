"""The DeepMimic, view-motion and char environments on the real MuJoCo engine."""

import math
import re
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch

from mimickit.engines.engine import ENGINES
from mimickit.envs.base_env import DoneFlags, EnvMode
from mimickit.envs.char_env import CharEnv
from mimickit.envs.deepmimic_env import DeepMimicEnv
from mimickit.envs.deepmimic_rewards import TERM_NAMES
from mimickit.envs.env_builder import build_env, load_env_configs
from mimickit.envs.env_config import CharEnvConfig
from mimickit.envs.view_motion_env import ViewMotionEnv
from mimickit.util import torch_util as tu
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA_DIR
from tests.conftest import PROJECT_HUMANOID
from tests.util.registry_checks import supported_list

ENGINE = PROJECT_DATA_DIR / "engines/mujoco_engine.yaml"
DEEPMIMIC = PROJECT_DATA_DIR / "envs/deepmimic_humanoid_env.yaml"
VIEW = PROJECT_DATA_DIR / "envs/view_motion_humanoid_env.yaml"


def make(env_file, num_envs=4, cls=None, **overrides):
    env_cfg, engine_cfg = load_env_configs(env_file, ENGINE)
    env_cfg = env_cfg.model_copy(update=overrides)
    if cls is None:
        return build_env(env_file, ENGINE, num_envs) if not overrides else DeepMimicEnv(env_cfg, engine_cfg, num_envs)
    return cls(env_cfg, engine_cfg, num_envs)


def pd_target_bounds(xml: Path) -> tuple[np.ndarray, np.ndarray]:
    """The pos-mode action bounds of MIMICKIT_SPEC.md §5.2 from MuJoCo's joint ranges: a body with three
    hinges is a spherical joint, ±1.2·max|limit|; one hinge is mid ± 1.4·max(|high−mid|, |low−mid|)."""
    m = mujoco.MjModel.from_xml_path(str(xml))
    low, high = [], []
    for b in range(2, m.nbody):  # bodies after the world and the free root
        r = m.jnt_range[m.body_jntadr[b] : m.body_jntadr[b] + m.body_jntnum[b]]
        if len(r) == 3:
            low += [-1.2 * np.abs(r).max()] * 3
            high += [1.2 * np.abs(r).max()] * 3
        elif len(r) == 1:
            mid, half = r[0].mean(), 1.4 * np.abs(r[0] - r[0].mean()).max()
            low, high = low + [mid - half], high + [mid + half]
    return np.array(low), np.array(high)


def test_observation_and_action_sizes():
    env = make(DEEPMIMIC)
    # MIMICKIT_SPEC.md §5.3: char obs 140 + phase obs 0 + 3 target steps × (root pos 3 + root rot 6
    # + 14 joints × 6 + 5 key bodies × 3 = 108) = 140 + 324 = 464.
    assert env.get_obs_space().shape == (464,)
    assert env.get_action_space().shape == (28,)  # D = 28 (§8.1: 8 spherical joints × 3 + 4 hinges)
    low, high = pd_target_bounds(PROJECT_HUMANOID)  # e.g. elbow [0, 2.7925]: 1.396 ± 1.955 = [-0.5585, 3.351]
    np.testing.assert_allclose(env.get_action_space().low, low, rtol=1e-6)
    np.testing.assert_allclose(env.get_action_space().high, high, rtol=1e-6)
    env_cfg, engine_cfg = load_env_configs(DEEPMIMIC, ENGINE)
    fields = {k: getattr(env_cfg, k) for k in CharEnvConfig.model_fields}
    char = CharEnv(CharEnvConfig(**dict(fields, env_name="char")), engine_cfg, 2)
    # §5.2: root height 1 + root rot 6 + root vel 3 + root ang vel 3 + 14 joints × 6 + DoF vel 28 + 5 key
    # bodies × 3 = 1 + 6 + 3 + 3 + 84 + 28 + 15 = 140.
    assert char.get_obs_space().shape == (140,)


def test_reference_state_scores_one():
    env = make(DEEPMIMIC, num_envs=8)
    env.reset()
    info = env.score_state()  # the reward terms a step computes, for the reset state itself
    terms = info["reward_terms"]
    assert set(terms) == set(TERM_NAMES)  # every term, the reference's five and any added beside them
    for name, value in terms.items():
        torch.testing.assert_close(value, torch.ones(8), atol=1e-3, rtol=0, msg=name)
    total = sum(env.reward_weights[k] * terms[k] for k in terms)
    torch.testing.assert_close(total, torch.ones(8), atol=1e-3, rtol=0)
    assert info["tracking"]["body_pos_err"].max() < 1e-4


def test_view_motion_matches_kinematics(test_data):
    walk = test_data / "motions/humanoid/humanoid_walk.pkl"
    env = make(VIEW, num_envs=2, cls=ViewMotionEnv, motion_file=str(walk))
    env.reset()
    lib, char = env.motion_lib, env.char_model
    worst = 0.0
    for _ in range(40):
        env.step(torch.zeros(2, 28))
        t = env.get_env_time()
        f = lib.calc_motion_frame(torch.zeros(2, dtype=torch.long), t)
        body_pos, _ = char.forward_kinematics(f.root_pos, f.root_rot, f.joint_rot)
        sim = env.engine.get_body_pos(env.get_char_id())
        worst = max(worst, (sim - body_pos).norm(dim=-1).max().item())
    assert worst < 1e-3


def test_pd_holds_init_pose_for_five_seconds():
    env_cfg, engine_cfg = load_env_configs(DEEPMIMIC, ENGINE)
    fields = {k: getattr(env_cfg, k) for k in CharEnvConfig.model_fields}
    env = CharEnv(CharEnvConfig(**dict(fields, env_name="char", episode_length=100.0)), engine_cfg, 2)
    env.reset()
    target = env.engine.get_dof_pos(env.get_char_id()).clone()  # the init pose the reset set
    steps = int(5.0 * engine_cfg.control_freq)
    heights = []
    for _ in range(steps):
        env.step(target)
        heights.append(env.engine.get_root_pos(env.get_char_id())[:, 2].clone())
    h = torch.stack(heights)
    assert (h - env_cfg.init_pose[2]).abs().max() < 0.05  # within 5 cm of the init pose's root height


def test_fall_is_fail_and_time_limit_is_time():
    env = make(DEEPMIMIC, num_envs=2, pose_termination=False)
    env.reset()
    e, c = env.engine, env.get_char_id()
    # Env 0 lies on its back on the floor: the torso touches the ground.
    lying = tu.quat_from_axis_angle(torch.tensor([0.0, 1.0, 0.0]), torch.tensor(-math.pi / 2))
    e.set_root_pos(torch.tensor([0]), c, torch.tensor([[0.0, 0.0, 0.09]]))  # the pelvis sphere's radius, §8.1
    e.set_root_rot(torch.tensor([0]), c, lying.unsqueeze(0))
    e.set_root_vel(torch.tensor([0]), c, 0.0)
    _, _, done, _ = env.step(env.engine.get_dof_pos(c).clone())
    assert done[0] == DoneFlags.FAIL
    short = make(DEEPMIMIC, num_envs=2, episode_length=0.2, enable_early_termination=False)
    short.reset()
    # 0.2 s at the engine yaml's 30 Hz control rate is 6 steps: the 6th (index 5) reaches the time limit.
    flags = [short.step(short.engine.get_dof_pos(0).clone())[2].clone() for _ in range(6)]
    assert (flags[4] == DoneFlags.NULL).all() and (flags[5] == DoneFlags.TIME).all()


def test_reset_one_env_leaves_others():
    env = make(DEEPMIMIC, num_envs=3)
    env.reset()
    for _ in range(3):
        obs_before = env.step(env.engine.get_dof_pos(0).clone())[0].clone()
    before = {k: v.clone() for k, v in env.get_char_state().items()}
    obs, _ = env.reset(torch.tensor([1]))
    after = env.get_char_state()
    for k in before:
        torch.testing.assert_close(after[k][[0, 2]], before[k][[0, 2]], msg=k)
    torch.testing.assert_close(obs[[0, 2]], obs_before[[0, 2]])


def test_mimickit_style_yaml_with_isaac_engine_block(tmp_path):
    text = DEEPMIMIC.read_text() + "\nengine:\n    engine_name: isaac_gym\n    sim_freq: 120\n    sim: {substeps: 2}\n"
    f = tmp_path / "deepmimic_env.yaml"
    f.write_text(text)
    with pytest.warns(UserWarning, match="ignored"):
        env_cfg, engine_cfg = load_env_configs(f, ENGINE)
    assert engine_cfg.engine_name == "mujoco" and engine_cfg.sim_freq != 120
    with pytest.raises(MimicKitError, match=re.escape(supported_list(ENGINES))):
        load_env_configs(f, None)


def test_unknown_env_key_is_named(tmp_path):
    f = tmp_path / "env.yaml"
    f.write_text(DEEPMIMIC.read_text().replace("rand_reset: True", "rand_rest: True"))
    with pytest.raises(MimicKitError, match="unknown key 'rand_rest'"):
        load_env_configs(f, ENGINE)


@pytest.mark.integration
def test_bench_json_reports_ratio():
    import json
    import subprocess
    import sys

    r = subprocess.run(
        [sys.executable, "-m", "mimickit.cli", "bench", "--num_envs", "8", "--steps", "5", "--json"],
        capture_output=True, text=True, cwd=PROJECT_DATA_DIR.parent,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert {"num_envs", "substeps", "env_steps_per_s", "raw_sim_steps_per_s", "ratio"} <= set(out)
    assert out["num_envs"] == 8 and out["substeps"] == 8  # sim_freq 240 / control_freq 30 (mujoco_engine.yaml)
    assert out["ratio"] == pytest.approx(out["env_steps_per_s"] * 8 / out["raw_sim_steps_per_s"], rel=1e-3)
    assert out["raw_mode"] == "free"
    r = subprocess.run(
        [sys.executable, "-m", "mimickit.cli", "bench", "--num_envs", "8", "--steps", "5", "--raw", "replay", "--json"],
        capture_output=True, text=True, cwd=PROJECT_DATA_DIR.parent,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["raw_mode"] == "replay" and out["raw_sim_steps_per_s"] > 0


def test_replay_in_rollout_redoes_the_env_step():
    """`bench --raw replay` times mujoco.rollout re-running each env step: from the engine's start state
    (a reset's pending edits included), warm start and controls, rollout must land exactly where the env's
    step did, so the baseline does the same physics work."""
    from mimickit.engines.bench_util import RawRollout

    env = make(DEEPMIMIC, num_envs=6)
    engine = env.engine
    env.reset()
    gen = torch.Generator().manual_seed(3)
    low, high = (torch.as_tensor(b) for b in (env.get_action_space().low, env.get_action_space().high))
    raw = RawRollout(engine.mj_model, engine.mj_datas, 2, engine.config.substeps)
    for i in range(4):
        if i == 2:
            env.reset(torch.tensor([0, 5]))  # edits the next step pushes
        state, warm = engine.physics_state()
        env.step(low + (high - low) * torch.rand(6, low.shape[0], generator=gen))
        raw.replay(state, warm, engine.get_ctrl())
        after, _ = engine.physics_state()
        np.testing.assert_array_equal(raw.last_state, after)
    raw.close()


def test_shifted_reference_equals_full_evaluation():
    """Per step only the newest target column is evaluated; the shifted buffers must equal a fresh
    evaluation of every column at the current motion time, across resets of some envs."""
    env = make(DEEPMIMIC, num_envs=6)
    env.reset()
    for i in range(12):
        env.step(torch.zeros(6, env.get_action_space().shape[0]))
        if i == 4:
            env.reset(torch.tensor([1, 3]))
    shifted = {k: v.clone() for k, v in env.get_ref_frames().items()}
    fresh = env.eval_ref_frames(torch.arange(6))
    for k, v in fresh.items():
        torch.testing.assert_close(shifted[k], v, atol=1e-4, rtol=0, msg=k)


@pytest.mark.parametrize("global_obs", [True, False])
def test_step_observation_equals_one_computed_afresh(global_obs):
    """A step's target features come from the clock work, computed while the physics runs; they must
    equal the observation computed from scratch for the same envs, also right after some envs reset."""
    env = make(DEEPMIMIC, num_envs=5, global_obs=global_obs)
    env.reset()
    gen = torch.Generator().manual_seed(2)
    low, high = (torch.as_tensor(b) for b in (env.get_action_space().low, env.get_action_space().high))
    for i in range(6):
        obs, _, _, _ = env.step(low + (high - low) * torch.rand(5, low.shape[0], generator=gen))
        torch.testing.assert_close(obs, env.compute_obs(torch.arange(5)), atol=0, rtol=0)
        if i == 2:
            env.reset(torch.tensor([0, 4]))  # the reset envs' frames change: the next step's must follow


@pytest.mark.parametrize("global_obs", [False, True])
def test_reset_observation_is_the_engine_state_observed(global_obs):
    """A reset observes the state it set (the reference frame) without asking the engine, which then
    pushes the edit at the next step without a kinematics pass: that observation must equal the one
    computed from the engine's own state, and the step after the reset must be the same either way."""
    envs = [make(DEEPMIMIC, num_envs=6, global_obs=global_obs) for _ in range(2)]
    gen = torch.Generator().manual_seed(4)
    low, high = (torch.as_tensor(b) for b in (envs[0].get_action_space().low, envs[0].get_action_space().high))
    action = low + (high - low) * torch.rand(6, low.shape[0], generator=gen)
    ids = torch.tensor([1, 3, 4])
    for k, env in enumerate(envs):
        torch.manual_seed(0)  # the same reset samples
        env.reset()
        env.step(action)
        obs, _ = env.reset(ids)
        assert env.engine.pending_edits()[ids.numpy()].all()  # the reset did not read the engine (no sync yet)
        if k == 1:  # read the engine: this syncs its kinematics for the reset envs before the next step
            from_engine = env.compute_obs(ids)
            torch.testing.assert_close(obs[ids], from_engine, atol=1e-5, rtol=0)
    outs = [env.step(action) for env in envs]
    for a, b in zip(outs[0][:3], outs[1][:3], strict=True):
        assert torch.equal(a, b)  # obs, reward, done: the unread edit stepped exactly as the synced one


def test_reset_records_tracking_in_test_mode_only():
    env = make(DEEPMIMIC, num_envs=4)
    env.reset()
    _, _, _, info = env.step(env.engine.get_dof_pos(0).clone())
    after_step = {k: v.clone() for k, v in info["tracking"].items()}
    assert after_step["dof_vel_err"].min() > 0  # a step off the clip
    _, info = env.reset(torch.tensor([0, 2]))
    for k, v in info["tracking"].items():
        assert torch.equal(v, after_step[k]), k  # training: the last step's values stay
    env.set_mode(EnvMode.TEST)
    _, info = env.reset(torch.tensor([0, 2]))
    assert info["tracking"]["body_pos_err"][[0, 2]].max() < 1e-6  # the reset state is the reference
    assert torch.equal(info["tracking"]["dof_vel_err"][[1, 3]], after_step["dof_vel_err"][[1, 3]])
    assert env.tracking_summary()["body_pos_err"] < 1e-6  # and recorded, as the reference does in TEST mode


def test_resets_take_their_states_from_the_pool_evaluated_ahead():
    """The clock work evaluates reset states ahead (sampled motion and time, every target column); a reset
    takes them from that pool, and samples and evaluates afresh what the pool lacks. Either way the env's
    frames are the clip at its new motion time, and a state is used once."""
    env = make(DEEPMIMIC, num_envs=8)
    env.reset()  # 8 resets: the pool is sized from the recent reset rate
    zeros = torch.zeros(8, env.get_action_space().shape[0])
    env.step(zeros)
    pool_ids, pool_times = env.get_reset_pool()
    pooled = len(pool_ids)
    assert pooled >= 2
    env.reset(torch.tensor([2, 5]))  # from the pool
    reset_ids = torch.tensor([2, 5])
    torch.testing.assert_close(env.get_motion_time(reset_ids), pool_times[:2], atol=0, rtol=0)
    assert torch.equal(env.get_motion_ids(reset_ids), pool_ids[:2])
    assert len(env.get_reset_pool()[0]) == pooled - 2
    env.reset(torch.arange(8))  # more than the pool holds: the rest sampled now
    assert len(env.get_reset_pool()[0]) == 0
    fresh = env.eval_ref_frames(torch.arange(8))
    frames = env.get_ref_frames()
    for k, v in fresh.items():
        torch.testing.assert_close(frames[k], v, atol=0, rtol=0, msg=k)
    assert len(set(env.get_motion_time().tolist())) == 8  # no state drawn twice (the clocks are at 0)
    # Without random reset times every pooled state starts its clip.
    still = make(DEEPMIMIC, num_envs=4, rand_reset=False)
    still.reset()
    still.step(torch.zeros(4, still.get_action_space().shape[0]))
    still_times = still.get_reset_pool()[1]
    assert len(still_times) > 0 and still_times.abs().max() == 0
