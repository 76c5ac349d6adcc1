"""The MuJoCo engine: model build, state conventions, PD control, contacts, resets and config errors."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch

from mimickit.anim.mjcf_char_model import load_char_model
from mimickit.engines.engine import ControlMode, EngineConfig, ObjType
from mimickit.engines.engine_builder import build_engine
from mimickit.engines.mujoco_engine import MujocoEngine, guided_chunks
from mimickit.util import torch_util as tu
from mimickit.util.config import load_config
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA_DIR
from tests import conftest
from tests.conftest import PROJECT_HUMANOID
from tests.engines import humanoid_cases
from tests.engines.humanoid_cases import INIT_ROOT_POS, init_dof

R_SHOULDER, L_SHOULDER = slice(6, 9), slice(10, 13)  # exp-map columns in the humanoid DoF layout


@pytest.fixture(scope="module")
def humanoid_xml() -> Path:
    """The project's humanoid if present, else MimicKit's from the reference data."""
    if PROJECT_HUMANOID.is_file():
        return PROJECT_HUMANOID
    data = conftest.test_data_dir()
    if data is None:
        pytest.skip("no humanoid MJCF: data/assets/humanoid/humanoid.xml is missing and MIMICKIT_TEST_DATA is unset")
    return data / "assets" / "humanoid" / "humanoid.xml"


def make_engine(xml: Path, num_envs: int = 1, mode: str = "pos", objs: tuple[dict, ...] = ({},)) -> MujocoEngine:
    """An initialized engine (30 Hz control, 240 Hz sim); `objs` are extra create_obj kwargs per object."""
    cfg = EngineConfig(engine_name="mujoco", control_mode=mode, control_freq=30, sim_freq=240, env_spacing=5)
    engine = MujocoEngine(cfg, num_envs, "cpu")
    for _ in range(num_envs):
        env_id = engine.create_env()
        for i, kwargs in enumerate(objs):
            args = {"start_pos": INIT_ROOT_POS, **kwargs}
            engine.create_obj(env_id, ObjType.articulated, str(args.pop("asset", xml)), f"obj{i}", **args)
    engine.initialize_sim()
    return engine


def random_dof(engine: MujocoEngine, n: int, gen: torch.Generator, margin: float = 0.9) -> torch.Tensor:
    """[n, D] DoFs inside the limits; spherical exp-maps kept below π in norm so that they round-trip."""
    low, high = (torch.from_numpy(x).float() for x in engine.get_obj_dof_limits(0, 0))
    mid, half = (low + high) / 2, (high - low) / 2 * margin
    dof = mid + half * (2 * torch.rand(n, len(low), generator=gen) - 1)
    kin = engine.obj_layout(0).kin
    for j in kin.joints[1:]:
        if j.dof_dim == 3:
            e = dof[:, j.dof_idx : j.dof_idx + 3]
            norm = e.norm(dim=-1, keepdim=True)
            dof[:, j.dof_idx : j.dof_idx + 3] = torch.where(norm > 2.8, e * 2.8 / norm, e)
    return dof


def random_quat(n: int, gen: torch.Generator) -> torch.Tensor:
    return tu.quat_normalize(torch.randn(n, 4, generator=gen))


def assert_quat_close(a: torch.Tensor, b: torch.Tensor, atol: float) -> None:
    """Quaternions equal up to sign (q and -q are the same rotation)."""
    err = torch.minimum((a - b).abs().amax(-1), (a + b).abs().amax(-1))
    assert err.max().item() < atol, err.max().item()


# ---------------------------------------------------------------------------------------------- model
def test_model_matches_kinematic_character(humanoid_xml):
    engine = make_engine(humanoid_xml)
    kin = load_char_model(humanoid_xml)
    assert engine.get_obj_body_names(0) == kin.get_body_names()
    assert engine.get_obj_num_bodies(0) == 15 and engine.get_obj_num_dofs(0) == 28
    assert engine.find_obj_body_id(0, "left_foot") == 14
    assert engine.calc_obj_mass(0, 0) == pytest.approx(50.05, rel=0.02)
    low, high = engine.get_obj_dof_limits(0, 0)
    np.testing.assert_allclose(low, kin.dof_limits()[0])
    np.testing.assert_allclose(high, kin.dof_limits()[1])
    np.testing.assert_allclose(engine.get_obj_torque_limits(0, 0), kin.dof_array("torque_limit"))
    kp, kd = engine.get_obj_pd_gains(0, 0)
    np.testing.assert_allclose(kp, kin.dof_array("kp"))
    np.testing.assert_allclose(kd, kin.dof_array("kd"))
    assert engine.get_timestep() == pytest.approx(1 / 30) and engine.get_sim_timestep() == pytest.approx(1 / 240)
    np.testing.assert_allclose(engine.get_gravity(), [0, 0, -9.81])
    m = engine.mj_model
    # 8 ball joints + 4 hinges + free root; passive springs gone; per-axis armature kept on the balls
    assert np.sum(m.jnt_type == mujoco.mjtJoint.mjJNT_BALL) == 8 and m.nu == 28
    assert np.all(m.jnt_stiffness == 0) and np.all(m.dof_damping == 0)
    np.testing.assert_allclose(m.dof_armature[6:], kin.dof_array("armature"))


def test_body_poses_equal_kinematic_fk(humanoid_xml):
    engine = make_engine(humanoid_xml, num_envs=4)
    kin = load_char_model(humanoid_xml)

    def check() -> None:
        dof = engine.get_dof_pos(0)
        pos, rot = kin.forward_kinematics(engine.get_root_pos(0), engine.get_root_rot(0), kin.dof_to_rot(dof))
        torch.testing.assert_close(engine.get_body_pos(0), pos, atol=1e-4, rtol=0)
        assert_quat_close(engine.get_body_rot(0), rot, atol=1e-4)

    torch.testing.assert_close(engine.get_root_pos(0), torch.tensor([INIT_ROOT_POS] * 4))
    check()  # right after creation
    gen = torch.Generator().manual_seed(0)
    engine.set_root_rot(None, 0, random_quat(4, gen))
    engine.set_dof_pos(None, 0, random_dof(engine, 4, gen))
    check()  # right after a reset by the setters


def test_state_round_trips_and_velocity_frames(humanoid_xml):
    n = 5
    engine = make_engine(humanoid_xml, num_envs=n)
    gen = torch.Generator().manual_seed(1)
    state = {
        "root_pos": torch.randn(n, 3, generator=gen) + torch.tensor([0.0, 0.0, 1.0]),
        "root_rot": random_quat(n, gen),
        "root_vel": torch.randn(n, 3, generator=gen),
        "root_ang_vel": torch.randn(n, 3, generator=gen),
        "dof_pos": random_dof(engine, n, gen),
        "dof_vel": torch.randn(n, 28, generator=gen),
    }
    for name, value in state.items():  # each setter keeps what the others set (world-frame velocities)
        getattr(engine, f"set_{name}")(None, 0, value)
    for name, value in state.items():
        got = getattr(engine, f"get_{name}")(0)
        if name == "root_rot":
            assert_quat_close(got, value, atol=1e-6)
        else:
            torch.testing.assert_close(got, value, atol=1e-5, rtol=1e-5, msg=name)

    # Body states (the body sensors): world frame, velocities at each body's centre of mass, as MuJoCo's
    # own MjData and mj_objectVelocity say, after the setters and after a step.
    m, res = engine.mj_model, np.zeros(6)
    for stepped in (False, True):
        if stepped:
            engine.set_cmd(0, state["dof_pos"])
            engine.step()
        for e in range(n):
            d = engine.mj_datas[e]
            for b, body_id in enumerate(engine.obj_layout(0).body_ids):
                mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_BODY, int(body_id), res, 0)
                np.testing.assert_allclose(engine.get_body_ang_vel(0)[e, b], res[:3], atol=1e-4)
                np.testing.assert_allclose(engine.get_body_vel(0)[e, b], res[3:], atol=1e-4)
                np.testing.assert_allclose(engine.get_body_pos(0)[e, b], d.xpos[body_id], atol=1e-6)
                np.testing.assert_allclose(engine.get_body_rot(0)[e, b], d.xquat[body_id][[1, 2, 3, 0]], atol=1e-6)


def test_joint_rotations_are_the_dofs_as_rotations_both_ways(humanoid_xml):
    """get_joint_rot reads MuJoCo's ball quaternions and hinge angles directly; it must equal the
    kinematic model's dof_to_rot of get_dof_pos (up to sign), and set_joint_rot must set the DoFs that
    set_dof_pos of rot_to_dof would, also for only some envs."""
    n = 6
    engine = make_engine(humanoid_xml, num_envs=n)
    kin = engine.obj_layout(0).kin
    gen = torch.Generator().manual_seed(7)
    dof = random_dof(engine, n, gen)
    engine.set_dof_pos(None, 0, dof)
    assert_quat_close(engine.get_joint_rot(0), kin.dof_to_rot(engine.get_dof_pos(0)), atol=1e-6)
    assert tuple(engine.get_joint_rot(0).shape) == (n, kin.get_num_joints() - 1, 4)

    rot = kin.dof_to_rot(random_dof(engine, 2, gen))
    engine.set_joint_rot(torch.tensor([1, 4]), 0, rot)
    expected = dof.clone()
    expected[[1, 4]] = kin.rot_to_dof(rot)
    torch.testing.assert_close(engine.get_dof_pos(0), expected, atol=1e-5, rtol=0)
    assert_quat_close(engine.get_joint_rot(0)[[1, 4]], rot, atol=1e-6)


def test_set_root_state_equals_the_four_root_setters(humanoid_xml):
    n, ids = 4, torch.tensor([0, 2])
    one_call, four_calls = make_engine(humanoid_xml, num_envs=n), make_engine(humanoid_xml, num_envs=n)
    gen = torch.Generator().manual_seed(3)
    for engine in (one_call, four_calls):  # both start moving, so that untouched rows have velocities to keep
        engine.set_root_vel(None, 0, torch.ones(n, 3))
        engine.set_root_ang_vel(None, 0, torch.full((n, 3), 0.5))
    pos, rot = torch.randn(2, 3, generator=gen) + torch.tensor([0.0, 0.0, 1.0]), random_quat(2, gen)
    vel, ang_vel = torch.randn(2, 3, generator=gen), torch.randn(2, 3, generator=gen)
    one_call.set_root_state(ids, 0, pos, rot, vel, ang_vel)
    four_calls.set_root_pos(ids, 0, pos)
    four_calls.set_root_rot(ids, 0, rot)
    four_calls.set_root_vel(ids, 0, vel)
    four_calls.set_root_ang_vel(ids, 0, ang_vel)
    for name in ("root_pos", "root_rot", "root_vel", "root_ang_vel", "body_pos", "body_vel"):
        torch.testing.assert_close(getattr(one_call, f"get_{name}")(0), getattr(four_calls, f"get_{name}")(0), msg=name)
    torch.testing.assert_close(one_call.get_root_vel(0)[ids], vel, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(one_call.get_root_ang_vel(0)[[1, 3]], torch.full((2, 3), 0.5), atol=1e-5, rtol=1e-5)


def test_setting_only_some_envs_and_broadcast_values(humanoid_xml):
    engine = make_engine(humanoid_xml, num_envs=3)
    before = engine.get_root_pos(0).clone()
    engine.set_root_pos(torch.tensor([1]), 0, torch.tensor([[1.0, 2.0, 3.0]]))
    engine.set_dof_vel(torch.tensor([0, 2]), 0, 0.0)  # scalars broadcast
    pos = engine.get_root_pos(0)
    torch.testing.assert_close(pos[1], torch.tensor([1.0, 2.0, 3.0]))
    torch.testing.assert_close(pos[[0, 2]], before[[0, 2]])


# ---------------------------------------------------------------------------------------------- control
def test_pd_holds_the_init_pose_for_5_seconds(humanoid_xml):
    engine = make_engine(humanoid_xml)
    engine.set_dof_pos(None, 0, init_dof())
    engine.set_cmd(0, init_dof())
    heights = []
    for _ in range(150):  # 5 s at 30 Hz
        engine.step()
        heights.append(engine.get_root_pos(0)[0, 2].item())
    assert max(abs(h - INIT_ROOT_POS[2]) for h in heights) < 0.05, (min(heights), max(heights))
    up = tu.quat_rotate(engine.get_root_rot(0), torch.tensor([[0.0, 0.0, 1.0]]))
    assert up[0, 2].item() > 0.99  # still upright


def test_ball_joint_actuator_length_is_the_exp_map(humanoid_xml):
    """What the engine relies on to drive exp-map targets: a ball-joint actuator with gear e_i has
    length = exp-map component i."""
    engine = make_engine(humanoid_xml, num_envs=3)
    engine.set_dof_pos(None, 0, random_dof(engine, 3, torch.Generator().manual_seed(2)))
    dof = engine.get_dof_pos(0).double().numpy()
    for e, d in enumerate(engine.mj_datas):
        mujoco.mj_forward(engine.mj_model, d)
        np.testing.assert_allclose(d.actuator_length[engine.obj_layout(0).act_ids], dof[e], atol=1e-5)


def test_ball_joint_pd_reaches_an_exp_map_target(humanoid_xml):
    engine = make_engine(humanoid_xml, objs=({"fix_root": True, "start_pos": (0.0, 0.0, 1.5)},))
    engine.mj_model.opt.gravity[:] = 0.0  # exact convergence: no sag under the arm's weight
    target = init_dof()
    target[0, R_SHOULDER] = torch.tensor([0.9, -0.4, 0.6])  # all three components non-zero
    target[0, 0:3] = torch.tensor([0.2, 0.3, -0.25])  # abdomen
    engine.set_cmd(0, target)
    for _ in range(60):  # 2 s
        engine.step()
    torch.testing.assert_close(engine.get_dof_pos(0), target, atol=2e-3, rtol=0)


@pytest.mark.parametrize("mode", ["pos", "vel", "torque", "none"])
def test_actuator_gains_follow_the_control_mode(humanoid_xml, mode):
    engine = make_engine(humanoid_xml, mode=mode)
    m, kin = engine.mj_model, load_char_model(humanoid_xml)
    kp, kd, limit = kin.dof_array("kp"), kin.dof_array("kd"), kin.dof_array("torque_limit")
    if mode == "none":
        assert m.nu == 0 and not engine.get_obj_pd_gains(0, 0)[0].any()
        return
    gain, bias = m.actuator_gainprm[:, 0], m.actuator_biasprm[:, :3]
    expected = {
        "pos": (kp, np.stack([0 * kp, -kp, -kd], -1), kp, kd),
        "vel": (kd, np.stack([0 * kp, 0 * kp, -kd], -1), 0 * kp, kd),
        "torque": (1 + 0 * kp, np.zeros((28, 3)), 0 * kp, 0 * kd),
    }[mode]
    np.testing.assert_allclose(gain, expected[0])
    np.testing.assert_allclose(bias, expected[1])
    np.testing.assert_allclose(engine.get_obj_pd_gains(0, 0)[0], expected[2])
    np.testing.assert_allclose(engine.get_obj_pd_gains(0, 0)[1], expected[3])
    np.testing.assert_allclose(m.actuator_forcerange[:, 1], limit)  # clipped to ± the torque limit


def test_pd_explicit_drives_a_hinge(tmp_path):
    xml = tmp_path / "arm.xml"
    xml.write_text(
        """<mujoco><worldbody><body name="base"><geom type="box" size=".05 .05 .05" mass="1"/>
        <body name="link"><joint name="elbow" type="hinge" axis="0 1 0" stiffness="50" damping="5"
         actuatorfrcrange="-20 20"/><geom type="capsule" fromto="0 0 0 .3 0 0" size=".03" mass="0.5"/>
        </body></body></worldbody></mujoco>"""
    )
    engine = make_engine(xml, mode="pd_1d", objs=({"fix_root": True, "start_pos": (0.0, 0.0, 1.0)},))
    assert engine.get_control_mode() == ControlMode.pd_explicit
    engine.mj_model.opt.gravity[:] = 0.0
    engine.set_cmd(0, torch.tensor([[0.5]]))
    for _ in range(30):
        engine.step()
    assert engine.get_dof_pos(0)[0, 0].item() == pytest.approx(0.5, abs=1e-3)


# ---------------------------------------------------------------------------------------------- resets
def test_resetting_one_env_leaves_the_others_untouched(humanoid_xml):
    gen = torch.Generator().manual_seed(3)
    cmds = [random_dof(make_engine(humanoid_xml, 3), 3, gen) for _ in range(10)]
    a, b = make_engine(humanoid_xml, num_envs=3), make_engine(humanoid_xml, num_envs=3)
    for eng in (a, b):
        eng.set_dof_pos(None, 0, init_dof(3))
    for cmd in cmds[:5]:
        for eng in (a, b):
            eng.set_cmd(0, cmd)
            eng.step()
    reset = torch.tensor([1])
    a.set_root_pos(reset, 0, torch.tensor([[0.0, 0.0, 1.2]]))
    a.set_root_rot(reset, 0, torch.tensor([[0.0, 0.0, 0.0, 1.0]]))
    a.set_root_vel(reset, 0, 0.0)
    a.set_root_ang_vel(reset, 0, 0.0)
    a.set_dof_pos(reset, 0, init_dof())
    a.set_dof_vel(reset, 0, 0.0)
    others = [0, 2]
    for k in range(6):
        for name in ("root_pos", "root_rot", "root_vel", "dof_pos", "dof_vel", "body_pos", "contact_forces"):
            got, ref = getattr(a, f"get_{name}")(0), getattr(b, f"get_{name}")(0)
            assert torch.equal(got[others], ref[others]), (name, k)
        if k == 0:
            torch.testing.assert_close(a.get_root_pos(0)[1], torch.tensor([0.0, 0.0, 1.2]))
        if k < 5:
            for eng in (a, b):
                eng.set_cmd(0, cmds[5 + k])
                eng.step()


def test_threaded_stepping_equals_one_thread(humanoid_xml):
    engines = []
    for threads in (1, 2):
        cfg = EngineConfig(engine_name="mujoco", control_mode="pos", control_freq=30, sim_freq=240, env_spacing=5,
                           num_threads=threads)  # fmt: skip
        engine = MujocoEngine(cfg, 5, "cpu")
        for _ in range(5):
            engine.create_obj(engine.create_env(), ObjType.articulated, str(humanoid_xml), "h", start_pos=INIT_ROOT_POS)
        engine.initialize_sim()
        engines.append(engine)
    gen = torch.Generator().manual_seed(4)
    for _ in range(5):
        cmd = random_dof(engines[0], 5, gen)
        for engine in engines:
            engine.set_cmd(0, cmd)
            engine.step()
    assert torch.equal(engines[0].get_body_pos(0), engines[1].get_body_pos(0))
    engines[1].close()  # after close the calling thread steps every env itself
    engines[1].step()
    engines[0].step()
    assert torch.equal(engines[0].get_dof_pos(0), engines[1].get_dof_pos(0))


def test_concurrent_work_runs_once_per_step_and_leaves_the_physics_unchanged(humanoid_xml):
    """`with stepping(): fn()`: fn runs on the calling thread while the worker takes chunks of envs; every env
    ends bit-identical to a plain step, and an error in fn surfaces after the workers finish."""
    n = 37
    sizes = [c.stop - c.start for c in guided_chunks(n, 2)]
    assert sum(sizes) == n and sizes == sorted(sizes, reverse=True) and sizes[-1] == 1  # big first, single last
    engines = []
    for _ in range(2):
        cfg = EngineConfig(engine_name="mujoco", control_mode="pos", control_freq=30, sim_freq=240, env_spacing=5,
                           num_threads=2)  # fmt: skip
        engine = MujocoEngine(cfg, n, "cpu")
        for _ in range(n):
            engine.create_obj(engine.create_env(), ObjType.articulated, str(humanoid_xml), "h", start_pos=INIT_ROOT_POS)
        engine.initialize_sim()
        engines.append(engine)
    calls = []
    gen = torch.Generator().manual_seed(5)
    for _ in range(4):
        cmd = random_dof(engines[0], n, gen)
        for engine in engines:
            engine.set_cmd(0, cmd)
        engines[0].step()
        with engines[1].stepping():
            calls.append(torch.randn(256, 64).sum())
    assert len(calls) == 4
    assert torch.equal(engines[0].get_body_pos(0), engines[1].get_body_pos(0))
    assert torch.equal(engines[0].get_dof_vel(0), engines[1].get_dof_vel(0))

    def fail() -> None:
        raise ValueError("from the concurrent work")

    with pytest.raises(ValueError, match="concurrent work"), engines[1].stepping():
        fail()
    engines[1].step()  # the workers finished: the engine steps on


# ---------------------------------------------------------------------------------------------- contacts
def test_ground_contact_forces_carry_the_body_weight_on_the_feet(humanoid_xml):
    engine = make_engine(humanoid_xml)
    engine.set_dof_pos(None, 0, init_dof())
    engine.set_cmd(0, init_dof())
    for _ in range(45):  # 1.5 s: settled
        engine.step()
    ground = engine.get_ground_contact_forces(0)[0]  # [B, 3], acting on each body
    weight = engine.calc_obj_mass(0, 0) * 9.81
    feet = [engine.find_obj_body_id(0, "right_foot"), engine.find_obj_body_id(0, "left_foot")]
    total = ground.sum(0)
    assert total[2].item() == pytest.approx(weight, rel=0.05)
    assert ground[feet, 2].sum().item() == pytest.approx(total[2].item(), rel=1e-3)
    assert abs(total[0].item()) < 0.05 * weight and abs(total[1].item()) < 0.05 * weight
    assert (ground[feet, 2] > 0.2 * weight).all()  # both feet bear weight
    torch.testing.assert_close(engine.get_contact_forces(0)[0], ground)  # no other contacts

    # The same sums by hand from mj_contactForce: contact frame → world, signed to act on the body.
    m, d = engine.mj_model, engine.mj_datas[0]
    by_hand = np.zeros((m.nbody, 3))
    local = np.zeros(6)
    for i in range(d.ncon):
        c = d.contact[i]
        mujoco.mj_contactForce(m, d, i, local)
        world = c.frame.reshape(3, 3).T @ local[:3]  # force of geom1 on geom2, world frame
        by_hand[m.geom_bodyid[c.geom[0]]] -= world
        by_hand[m.geom_bodyid[c.geom[1]]] += world
    body_ids = engine.obj_layout(0).body_ids
    np.testing.assert_allclose(ground.double().numpy(), by_hand[body_ids], rtol=1e-4, atol=1e-3)


def test_visual_ghost_neither_collides_nor_falls(humanoid_xml):
    engine = make_engine(
        humanoid_xml,
        objs=(
            {},
            {
                "is_visual": True,
                "disable_motors": True,
                "color": (0.2, 0.6, 1.0),
                "start_pos": (0.3, 0, INIT_ROOT_POS[2]),
            },
        ),
    )
    assert engine.get_objs_per_env() == 2
    assert not engine.get_obj_pd_gains(0, 1)[0].any()
    engine.set_dof_pos(None, 0, init_dof())
    engine.set_cmd(0, init_dof())
    start = engine.get_body_pos(1).clone()
    for _ in range(30):
        engine.step()
    torch.testing.assert_close(engine.get_body_pos(1), start, atol=1e-3, rtol=0)  # gravity-compensated
    torch.testing.assert_close(engine.get_contact_forces(0), engine.get_ground_contact_forces(0))
    assert not engine.get_contact_forces(1).any()


def test_fixed_root_object_stays_and_moves_only_when_set(humanoid_xml):
    engine = make_engine(humanoid_xml, objs=({"fix_root": True, "start_pos": (1.0, 0.0, 1.5)},))
    assert engine.get_obj_num_dofs(0) == 28
    for _ in range(10):
        engine.step()
    torch.testing.assert_close(engine.get_root_pos(0), torch.tensor([[1.0, 0.0, 1.5]]))
    assert not engine.get_root_vel(0).any()
    engine.set_root_pos(None, 0, torch.tensor([[2.0, 1.0, 1.0]]))
    engine.set_root_rot(None, 0, torch.tensor([[0.0, 0.0, math.sin(0.5), math.cos(0.5)]]))
    engine.step()
    torch.testing.assert_close(engine.get_root_pos(0), torch.tensor([[2.0, 1.0, 1.0]]))
    assert_quat_close(engine.get_root_rot(0), torch.tensor([[0.0, 0.0, math.sin(0.5), math.cos(0.5)]]), 1e-6)


# ---------------------------------------------------------------------------------------------- config
def test_isaac_gym_config_is_one_clear_error():
    cfg = {"engine_name": "isaac_gym", "control_mode": "pos", "control_freq": 30, "sim_freq": 120, "env_spacing": 5}
    with pytest.raises(MimicKitError) as err:
        build_engine(cfg, 4, "cpu", source="data/engines/isaac_gym_engine.yaml")
    msg = str(err.value)
    assert "isaac_gym" in msg and "mujoco" in msg and "newton" in msg and "\n" not in msg
    assert msg.startswith("data/engines/isaac_gym_engine.yaml")


def test_newton_engine_names_its_install_extra():
    if importlib.util.find_spec("newton") is not None:
        pytest.skip("newton is installed in this venv (.venv-newton)")
    cfg = {"engine_name": "newton", "control_mode": "pos", "control_freq": 30, "sim_freq": 240, "env_spacing": 5}
    with pytest.raises(MimicKitError, match=r"pip install \.\[newton\]"):
        build_engine(cfg, 4, "cpu")


def test_engine_yaml_and_config_rules():
    cfg = load_config(EngineConfig, PROJECT_DATA_DIR / "engines" / "mujoco_engine.yaml")
    assert (cfg.engine_name, cfg.control_mode, cfg.control_freq, cfg.sim_freq) == ("mujoco", ControlMode.pos, 30, 240)
    assert cfg.substeps == 8 and cfg.env_spacing == 5 and cfg.ground_contact_height == 0.3
    base = {"engine_name": "mujoco", "env_spacing": 5}
    assert EngineConfig(**base, control_mode="pd_1d").control_mode == ControlMode.pd_explicit
    assert EngineConfig(**base, control_mode=3).control_mode == ControlMode.torque
    assert EngineConfig(**base).control_freq == 10 and EngineConfig(**base).sim_freq == 60
    with pytest.raises(MimicKitError, match="multiple of control_freq"):
        build_engine({**base, "control_freq": 30, "sim_freq": 100}, 1, "cpu")
    with pytest.raises(MimicKitError, match="unknown key 'substeps'"):
        build_engine({**base, "substeps": 4}, 1, "cpu")
    with pytest.raises(MimicKitError, match="unknown control mode"):
        build_engine({**base, "control_mode": "position"}, 1, "cpu")
    engine = build_engine({**base, "control_mode": "pos"}, 2, "cpu")
    assert isinstance(engine, MujocoEngine) and engine.get_name() == "mujoco"


def test_env_objects_must_match(humanoid_xml, tmp_path):
    cfg = EngineConfig(engine_name="mujoco", control_mode="pos", env_spacing=5)
    engine = MujocoEngine(cfg, 2, "cpu")
    engine.create_obj(engine.create_env(), ObjType.articulated, str(humanoid_xml), "humanoid")
    engine.create_obj(engine.create_env(), ObjType.articulated, str(humanoid_xml), "humanoid", fix_root=True)
    with pytest.raises(MimicKitError, match="identical object lists"):
        engine.initialize_sim()
    with pytest.raises(MimicKitError, match="not found"):
        engine.create_obj(0, ObjType.articulated, str(tmp_path / "missing.xml"), "x")


# ---------------------------------------------------------------------------------------------- pushes
def test_a_pelvis_push_moves_the_root_and_ends_after_its_duration(humanoid_xml):
    engine = make_engine(humanoid_xml, num_envs=2)
    out = humanoid_cases.push_standing(engine)
    assert out["steps"] == 6  # 0.2 s at 30 Hz
    assert [(f.env_id, f.obj_id, f.body_id, f.steps_left) for f in out["acting"]] == [(0, 0, 0, 6)]
    pos = out["root_pos"]
    dx = (pos[0, 0] - pos[1, 0]).item()
    assert dx > 0.1, pos  # pushed along +x, against the same run without the push
    assert abs(pos[1, 0].item()) < 0.05  # the unpushed twin stood where it was
    assert out["left"] == [] and not engine.mj_datas[0].xfrc_applied.any()  # gone after 0.2 s


def test_a_reset_ends_a_push_and_bad_pushes_are_refused(humanoid_xml):
    engine = make_engine(humanoid_xml, num_envs=2)
    engine.apply_body_force(1, 0, 3, [0.0, 200.0, 0.0], torque=[0.0, 0.0, 5.0], duration_s=1.0)
    body = engine.obj_layout(0).body_ids[3]
    assert engine.mj_datas[1].xfrc_applied[body].tolist() == [0.0, 200.0, 0.0, 0.0, 0.0, 5.0]
    engine.step()
    assert engine.get_body_forces(1)[0].steps_left == 29
    engine.set_root_state([0], 0, torch.tensor(INIT_ROOT_POS), torch.tensor([0.0, 0, 0, 1]), 0.0, 0.0)
    assert len(engine.get_body_forces()) == 1  # env 0's reset leaves env 1's push
    engine.set_root_state([1], 0, torch.tensor(INIT_ROOT_POS), torch.tensor([0.0, 0, 0, 1]), 0.0, 0.0)
    assert engine.get_body_forces() == [] and not engine.mj_datas[1].xfrc_applied.any()
    for bad, match in (
        ({"body_id": 99}, "bodies, not body 99"),
        ({"force": [float("nan"), 0, 0]}, "finite"),
        ({"force": [1.0, 2.0]}, "finite"),
        ({"duration_s": 0.0}, "positive"),
        ({"env_id": 2}, "out of range"),
    ):
        args = {"env_id": 0, "obj_id": 0, "body_id": 0, "force": [1.0, 0, 0], **bad}
        with pytest.raises(MimicKitError, match=match):
            engine.apply_body_force(**args)
