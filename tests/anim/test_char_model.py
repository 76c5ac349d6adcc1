"""The MJCF character model: structure, DoF layout, conversions and forward kinematics."""

import math
import warnings

import mujoco
import numpy as np
import pytest
import torch

from mimickit.anim.kin_char_model import JointType
from mimickit.anim.mjcf_char_model import load_char_model
from mimickit.anim.mjcf_loader import load_mjcf_model
from mimickit.envs.env_builder import load_env_configs
from mimickit.util import torch_util as tu
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA_DIR
from tests.conftest import PROJECT_HUMANOID


def test_project_humanoid_layout():
    """Checked against MuJoCo's own compile of the same MJCF: every joint of humanoid.xml below the free
    root is a one-DoF hinge (a spherical joint is three), so MuJoCo's joint k is our DoF k - 1."""
    c = load_char_model(PROJECT_HUMANOID)
    m = mujoco.MjModel.from_xml_path(str(PROJECT_HUMANOID))
    assert c.get_body_names() == [m.body(i).name for i in range(1, m.nbody)]  # body 0 is MuJoCo's world
    assert c.get_dof_size() == m.nv - 6 and c.get_num_joints() == m.nbody - 1
    types = [j.type for j in c.joints[1:]]
    # The spec's count (MIMICKIT_SPEC.md §8.1: "12 actuated joints (8 spherical, 4 hinge)", 2 fixed hands).
    assert types.count(JointType.SPHERICAL) == 8 and types.count(JointType.HINGE) == 4
    assert types.count(JointType.FIXED) == 2
    for body in ("right_lower_arm", "left_upper_arm", "left_foot"):  # a hinge, a ball after a hinge, the last
        b = m.body(body).id
        assert c.get_joint_dof_idx(c.get_body_id(body)) == m.jnt_dofadr[m.body_jntadr[b]] - 6, body
    assert c.get_total_mass() == pytest.approx(float(m.body_mass.sum()), rel=1e-6)  # 50.05 kg, §8.1
    low, high = c.dof_limits()
    np.testing.assert_allclose(low, m.jnt_range[1:, 0])
    np.testing.assert_allclose(high, m.jnt_range[1:, 1])
    np.testing.assert_allclose(c.dof_array("kp"), m.jnt_stiffness[1:])
    np.testing.assert_allclose(c.dof_array("torque_limit"), m.jnt_actfrcrange[1:, 1])


# Bodies and DoFs of each character: MIMICKIT_SPEC.md §8.1 (humanoid: 15 bodies, D = 28) and §8.2's table
# (SMPL 24 / 69, G1 31 / 29, Go2 17 / 12); MuJoCo cannot check them here, Go2's meshes are not shipped.
@pytest.mark.parametrize(
    "asset, bodies, dofs",
    [("humanoid/humanoid.xml", 15, 28), ("smpl/smpl.xml", 24, 69), ("g1/g1.xml", 31, 29), ("go2/go2.xml", 17, 12)],
)
def test_mimickit_characters_load(test_data, asset, bodies, dofs):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        c = load_char_model(test_data / "assets" / asset)
    assert (c.get_num_joints(), c.get_dof_size()) == (bodies, dofs)
    if asset.startswith("go2"):
        assert any("mesh file(s) missing" in str(x.message) for x in w)


def test_dof_rot_round_trip():
    c = load_char_model(PROJECT_HUMANOID)
    g = torch.Generator().manual_seed(0)
    dof = torch.zeros(500, 28)
    for j in c.joints[1:]:
        if j.type == JointType.HINGE:
            dof[:, j.dof_idx] = (torch.rand(500, generator=g) * 2 - 1) * (math.pi - 1e-3)
        elif j.type == JointType.SPHERICAL:
            axis = torch.nn.functional.normalize(torch.randn(500, 3, generator=g), dim=-1)
            dof[:, j.dof_idx : j.dof_idx + 3] = axis * torch.rand(500, 1, generator=g) * (math.pi - 1e-3)
    torch.testing.assert_close(c.rot_to_dof(c.dof_to_rot(dof)), dof, atol=2e-4, rtol=0)
    fixed = c.dof_to_rot(dof)[:, c.get_body_id("right_hand") - 1]
    torch.testing.assert_close(fixed, tu.quat_identity((500,)))


def _mj_body_pos(m, qpos):
    d = mujoco.MjData(m)
    d.qpos[:] = qpos
    mujoco.mj_kinematics(m, d)
    return d.xpos[1:].copy()


def test_fk_matches_mujoco_on_hinge_robot(test_data):
    """G1 is all hinges: MuJoCo's own kinematics is an independent check of our FK."""
    path = test_data / "assets/g1/g1.xml"
    c = load_char_model(path)
    m = load_mjcf_model(path)
    rng = np.random.default_rng(0)
    low, high = c.dof_limits()
    for _ in range(10):
        root_pos = rng.normal(size=3)
        root_q = rng.normal(size=4)
        root_q /= np.linalg.norm(root_q)  # wxyz for MuJoCo
        dof = rng.uniform(low, high)
        ours, _ = c.forward_kinematics(
            torch.tensor(root_pos, dtype=torch.float32),
            tu.quat_from_wxyz(torch.tensor(root_q, dtype=torch.float32)),
            c.dof_to_rot(torch.tensor(dof, dtype=torch.float32)),
        )
        ref = _mj_body_pos(m, np.concatenate([root_pos, root_q, dof]))
        np.testing.assert_allclose(ours.numpy(), ref, atol=1e-5)


def test_fk_matches_mujoco_on_humanoid_single_axis_joints():
    """With one axis per 3-hinge joint, the exp map equals that hinge's angle: compare with MuJoCo."""
    c = load_char_model(PROJECT_HUMANOID)
    m = load_mjcf_model(PROJECT_HUMANOID)
    rng = np.random.default_rng(1)
    for _ in range(10):
        dof = np.zeros(28)
        for j in c.joints[1:]:
            if j.type == JointType.HINGE:
                dof[j.dof_idx] = rng.uniform(j.low[0], j.high[0])
            elif j.type == JointType.SPHERICAL:
                a = rng.integers(3)
                dof[j.dof_idx + a] = rng.uniform(j.low[a], j.high[a])
        root_q = np.array([0.9, 0.1, -0.2, 0.3]) / np.linalg.norm([0.9, 0.1, -0.2, 0.3])
        ours, _ = c.forward_kinematics(
            torch.tensor([0.1, 0.2, 0.9]),
            tu.quat_from_wxyz(torch.tensor(root_q, dtype=torch.float32)),
            c.dof_to_rot(torch.tensor(dof, dtype=torch.float32)),
        )
        ref = _mj_body_pos(m, np.concatenate([[0.1, 0.2, 0.9], root_q, dof]))
        np.testing.assert_allclose(ours.numpy(), ref, atol=1e-5)


def test_project_humanoid_matches_mimickit_humanoid(ref_humanoid_xml):
    ours = load_char_model(PROJECT_HUMANOID)
    ref = load_char_model(ref_humanoid_xml)
    assert ours.get_body_names() == ref.get_body_names()
    assert [j.name for j in ours.joints] == [j.name for j in ref.joints]
    assert ours.get_total_mass() == pytest.approx(ref.get_total_mass(), rel=0.02)
    np.testing.assert_allclose(ours.body_mass, ref.body_mass, rtol=0.02)
    for attr in ("kp", "kd", "armature", "torque_limit"):
        np.testing.assert_allclose(ours.dof_array(attr), ref.dof_array(attr), err_msg=attr)
    g = torch.Generator().manual_seed(2)
    low, high = (torch.tensor(x, dtype=torch.float32) for x in ref.dof_limits())
    dof = low + (high - low) * torch.rand(20, 28, generator=g)
    root_pos = torch.randn(20, 3, generator=g)
    root_rot = tu.quat_normalize(torch.randn(20, 4, generator=g))
    a, _ = ours.forward_kinematics(root_pos, root_rot, ours.dof_to_rot(dof))
    b, _ = ref.forward_kinematics(root_pos, root_rot, ref.dof_to_rot(dof))
    assert (a - b).norm(dim=-1).max() < 1e-3


def test_init_pose_feet_on_ground():
    """The shipped env's init pose (root at 0.882416 m, arms down: MIMICKIT_SPEC.md §5.2) stands on its feet."""
    from mimickit.anim.char_geometry import body_surface_points, lowest_point_z

    c = load_char_model(PROJECT_HUMANOID)
    env_cfg, _ = load_env_configs(
        PROJECT_DATA_DIR / "envs/deepmimic_humanoid_env.yaml", PROJECT_DATA_DIR / "engines/mujoco_engine.yaml"
    )
    pose = torch.tensor([env_cfg.init_pose], dtype=torch.float32)  # root pos 3, root exp-map 3, DoFs
    assert not pose[0, 3:6].any()  # an upright root: its rotation is the identity below
    pos, rot = c.forward_kinematics(pose[:, :3], tu.quat_identity((1,)), c.dof_to_rot(pose[:, 6:]))
    ids, pts = body_surface_points(c, ["right_foot", "left_foot"])
    assert abs(lowest_point_z(c, ids, pts, pos, rot).item()) < 0.005


def test_unsupported_joints_are_named(tmp_path):
    f = tmp_path / "bad.xml"
    f.write_text(
        '<mujoco><worldbody><body name="base"><freejoint/><geom size=".1"/>'
        '<body name="arm"><joint name="a" type="hinge" axis="1 0 0"/><joint name="b" type="hinge" axis="0 1 0"/>'
        '<geom size=".1"/></body></body></worldbody></mujoco>'
    )
    with pytest.raises(MimicKitError, match="body 'arm'"):
        load_char_model(f)
    g = tmp_path / "broken.xml"
    g.write_text("<mujoco><worldbody><body")
    with pytest.raises(MimicKitError, match="broken.xml"):
        load_char_model(g)
