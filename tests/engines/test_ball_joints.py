"""Ball joints in the MuJoCo engine: cone limits (`ball_joint_limits`) and pd_explicit on exp-map DoFs.

The Newton engine's counterparts are in test_newton_engine.py (its own venv)."""

from __future__ import annotations

import warnings
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch

from mimickit.anim.mjcf_char_model import load_char_model
from mimickit.anim.motion_lib import MotionLib
from mimickit.engines.engine import EngineConfig, ObjType, ball_cone_angle
from mimickit.engines.mujoco_engine import MujocoEngine
from tests.conftest import PROJECT_HUMANOID
from tests.engines.humanoid_cases import (
    HANGING,
    INIT_ROOT_POS,
    PD_EXPLICIT_FREQ,
    ball_target,
    final_dofs_by_mode,
    init_dof,
    random_pd_state,
)

# DoF columns of two ball joints and their cones (largest |bound| of their hinge ranges) and torque limits,
# from MIMICKIT_SPEC.md §8.1: neck_y [−.6981, 1.0472], ±50; abdomen_y [−1.0472, 1.5708], ±200.
NECK, ABDOMEN = slice(3, 6), slice(0, 3)
CONES = {"neck": (NECK, 1.0472, 50.0), "abdomen": (ABDOMEN, 1.5708, 200.0)}  # (columns, cone, torque limit)


def make_engine(mode: str = "pos", sim_freq: int = 240, limits: str = "cone", integrator: str = "implicitfast",
                asset: Path = PROJECT_HUMANOID, **obj_kwargs) -> MujocoEngine:  # fmt: skip
    """One character (the humanoid) at 30 Hz control; `obj_kwargs` go to create_obj."""
    cfg = EngineConfig(engine_name="mujoco", control_mode=mode, control_freq=30, sim_freq=sim_freq, env_spacing=5,
                       ball_joint_limits=limits, integrator=integrator)  # fmt: skip
    engine = MujocoEngine(cfg, 1, "cpu")
    obj_kwargs.setdefault("start_pos", INIT_ROOT_POS)
    engine.create_obj(engine.create_env(), ObjType.articulated, str(asset), "char", **obj_kwargs)
    engine.initialize_sim()
    return engine


# ---------------------------------------------------------------------------------------------- limits
@pytest.mark.parametrize("limits", ["cone", "none"])
def test_ball_joints_get_the_cone_of_their_hinge_ranges(limits):
    engine = make_engine(limits=limits)
    m, kin = engine.mj_model, load_char_model(PROJECT_HUMANOID)
    for joint in kin.joints[1:]:
        if joint.dof_dim == 0:
            continue  # hands: no joint
        j = m.joint(engine.obj_layout(0).prefix + joint.name).id
        if joint.dof_dim == 1:
            assert m.jnt_limited[j]  # hinges keep their MJCF limits either way
            continue
        assert m.jnt_type[j] == mujoco.mjtJoint.mjJNT_BALL
        assert m.jnt_limited[j] == (limits == "cone"), joint.name
        if limits == "cone":
            cone = max(np.abs(joint.low).max(), np.abs(joint.high).max())
            np.testing.assert_allclose(m.jnt_range[j], [0.0, cone])
            # the limit's softness comes from the hinges (solimplimit "0 0.99 0.01" in the humanoid)
            np.testing.assert_allclose(m.jnt_solimp[j, :3], [0.0, 0.99, 0.01])
    assert ball_cone_angle(np.array([-0.5, -2.0, -1.0]), np.array([0.5, 1.0, 1.0])) == 2.0
    assert ball_cone_angle(np.full(3, -np.pi), np.full(3, np.pi)) is None  # a cone of π limits nothing


def test_cones_are_radians_when_the_mjcf_counts_in_degrees(test_data):
    """SMPL's MJCF leaves MuJoCo's default angle="degree": its compiled cones must still be the radian ones
    (a cone written in radians into a degree spec made its ankles' cone 0.017 rad and it fell at once)."""
    xml = test_data / "assets" / "smpl" / "smpl.xml"
    engine = make_engine(asset=xml)
    m, kin = engine.mj_model, load_char_model(xml)
    balls = [j for j in kin.joints[1:] if j.dof_dim == 3]
    assert len(balls) == 23
    for joint in balls:
        j = m.joint(engine.obj_layout(0).prefix + joint.name).id
        np.testing.assert_allclose(m.jnt_range[j], [0.0, ball_cone_angle(joint.low, joint.high)], rtol=1e-6)


@pytest.mark.parametrize("joint", ["neck", "abdomen"])
@pytest.mark.parametrize("limits", ["cone", "none"])
def test_a_large_torque_stops_at_the_cone_only_with_limits(joint, limits):
    """The torque limit about the joint's y axis for 1/3 s, self-collisions off (nothing else in the way): the
    limited joint has settled by then, the free one has swung past (and would spin up until MuJoCo's
    instability reset if it went on)."""
    cols, cone, torque = CONES[joint]
    engine = make_engine("torque", limits=limits, enable_self_collisions=False, **HANGING)
    cmd = torch.zeros(1, 28)
    cmd[0, cols.start + 1] = torque
    engine.set_cmd(0, cmd)
    angles = []
    for _ in range(10):
        engine.step()
        angles.append(engine.get_dof_pos(0)[0, cols].norm().item())
    if limits == "cone":
        # Measured (both engines): settles 9 mrad past the cone after a soft-limit overshoot of 0.13-0.17 rad.
        assert abs(angles[-1] - cone) < 0.02, angles[-1]
        assert max(angles) < cone + 0.25, max(angles)
    else:
        assert max(angles) > cone + 1.0, max(angles)  # measured: 2.92 (neck), 2.92 (abdomen)


def test_walk_clip_stays_inside_every_cone(test_data):
    """The shipped walk policy's clip never needs more than the cones (other clips do: EngineConfig docs)."""
    kin = load_char_model(PROJECT_HUMANOID)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the clip's NaN columns are sanitised with a warning
        lib = MotionLib(test_data / "motions" / "humanoid" / "humanoid_walk.pkl", kin)
    for joint in kin.joints[1:]:
        if joint.dof_dim == 3:
            angle = lib.dof_pos[:, joint.dof_idx : joint.dof_idx + 3].norm(dim=-1).max().item()
            assert angle < ball_cone_angle(joint.low, joint.high), (joint.name, angle)


# ---------------------------------------------------------------------------------------------- pd_explicit
def test_pd_explicit_is_the_pos_actuator_law_on_ball_joints():
    """Under Euler both modes apply the PD torque explicitly, so pd_explicit must reproduce pos exactly: the
    same τ = kp (q* − q) − kd ω per exp-map component, standing on the ground from a random moving state."""
    dof, vel, target = random_pd_state(torch.Generator().manual_seed(0))
    runs = {}
    for mode in ("pos", "pd_explicit"):
        engine = make_engine(mode, sim_freq=PD_EXPLICIT_FREQ, integrator="euler")
        engine.set_dof_pos(None, 0, dof)
        engine.set_dof_vel(None, 0, vel)
        engine.set_cmd(0, target)
        for _ in range(5):
            engine.step()
        runs[mode] = (engine.get_dof_pos(0).clone(), engine.get_body_pos(0).clone(), engine.get_dof_forces(0).clone())
    for a, b in zip(runs["pos"], runs["pd_explicit"], strict=True):
        torch.testing.assert_close(a, b, atol=1e-5, rtol=0)
    assert (runs["pos"][0] - dof).abs().max() > 0.1  # the joints did move


def test_pd_explicit_and_pos_agree_over_a_few_steps():
    """The default integrator treats pos mode's damping implicitly, pd_explicit's explicitly: O(dt) apart."""
    dof, vel, target = random_pd_state(torch.Generator().manual_seed(0))
    runs = {}
    for mode in ("pos", "pd_explicit"):
        engine = make_engine(mode, sim_freq=PD_EXPLICIT_FREQ, **HANGING)
        engine.set_dof_pos(None, 0, dof)
        engine.set_dof_vel(None, 0, vel)
        engine.set_cmd(0, target)
        runs[mode] = []
        for _ in range(5):
            engine.step()
            runs[mode].append((engine.get_dof_pos(0).clone(), engine.get_body_pos(0).clone()))
    # Measured: DoFs ≤ 17.6 mrad apart (first step, while the random velocities decay), bodies ≤ 4 mm; both
    # halve at 3840 Hz; by step 5 the DoFs are 2.6 mrad apart.
    for (q_pos, x_pos), (q_pd, x_pd) in zip(runs["pos"], runs["pd_explicit"], strict=True):
        assert (q_pos - q_pd).abs().max() < 0.03
        assert (x_pos - x_pd).norm(dim=-1).max() < 0.008
    assert (runs["pos"][-1][0] - runs["pd_explicit"][-1][0]).abs().max() < 0.005


@pytest.mark.slow
def test_pd_explicit_holds_the_standing_pose_like_pos():
    finals = {}
    for mode in ("pos", "pd_explicit"):
        engine = make_engine(mode, sim_freq=PD_EXPLICIT_FREQ)
        engine.set_dof_pos(None, 0, init_dof())
        engine.set_cmd(0, init_dof())
        heights = []
        for _ in range(150):  # 5 s
            engine.step()
            heights.append(engine.get_root_pos(0)[0, 2].item())
        assert max(abs(h - INIT_ROOT_POS[2]) for h in heights) < 0.05, (mode, min(heights))
        finals[mode] = engine.get_dof_pos(0).clone()
    torch.testing.assert_close(finals["pd_explicit"], finals["pos"], atol=2e-3, rtol=0)


def test_pd_explicit_reaches_a_ball_joint_target_like_pos():
    """A hanging humanoid, target with all three exp-map components non-zero: after 1 s pd_explicit sits
    where pos mode (at its usual 240 Hz) does, sagging under gravity alike (measured 1e-5 rad apart)."""
    target = ball_target()
    finals = final_dofs_by_mode(lambda mode, freq: make_engine(mode, sim_freq=freq, **HANGING), target, 30)
    assert (finals["pos"] - target).abs().max() < 0.05  # the gravity sag of kp-limited joints
    torch.testing.assert_close(finals["pd_explicit"], finals["pos"], atol=2e-3, rtol=0)


def test_pd_explicit_warns_when_its_damping_is_too_stiff_for_the_timestep():
    with pytest.warns(UserWarning, match=r"diverges at sim_freq 240 Hz .*ankle.*above 17\d\d Hz"):
        make_engine("pd_explicit")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        make_engine("pd_explicit", sim_freq=PD_EXPLICIT_FREQ)
