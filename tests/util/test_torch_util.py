import math

import torch

from mimickit.util import torch_util as tu


def q(x, y, z, w):
    return torch.tensor([x, y, z, w], dtype=torch.float32)


def test_quat_mul_composes_rotations_about_z():
    a = tu.quat_from_axis_angle(torch.tensor([0.0, 0.0, 1.0]), torch.tensor(math.pi / 2))
    ab = tu.quat_mul(a, a)  # 180° about z
    torch.testing.assert_close(tu.quat_pos(ab), q(0, 0, 1, 0), atol=1e-6, rtol=0)


def test_quat_rotate_hand_computed():
    rz90 = q(0, 0, math.sin(math.pi / 4), math.cos(math.pi / 4))
    torch.testing.assert_close(
        tu.quat_rotate(rz90, torch.tensor([1.0, 0, 0])), torch.tensor([0.0, 1, 0]), atol=1e-6, rtol=0
    )
    rx90 = q(math.sin(math.pi / 4), 0, 0, math.cos(math.pi / 4))
    torch.testing.assert_close(
        tu.quat_rotate(rx90, torch.tensor([0.0, 1, 0])), torch.tensor([0.0, 0, 1]), atol=1e-6, rtol=0
    )


def test_wxyz_conversion():
    x = q(0.1, 0.2, 0.3, 0.9)
    torch.testing.assert_close(tu.quat_to_wxyz(x), torch.tensor([0.9, 0.1, 0.2, 0.3]))
    torch.testing.assert_close(tu.quat_from_wxyz(tu.quat_to_wxyz(x)), x)


def test_exp_map_round_trip_and_values():
    e = torch.tensor([0.0, 0.0, math.pi / 2])
    torch.testing.assert_close(tu.exp_map_to_quat(e), q(0, 0, math.sin(math.pi / 4), math.cos(math.pi / 4)))
    g = torch.Generator().manual_seed(0)
    axis = torch.nn.functional.normalize(torch.randn(1000, 3, generator=g), dim=-1)
    angle = torch.rand(1000, 1, generator=g) * (math.pi - 1e-3)
    e = axis * angle
    torch.testing.assert_close(tu.quat_to_exp_map(tu.exp_map_to_quat(e)), e, atol=1e-4, rtol=0)


def test_exp_map_zero_and_wrap():
    torch.testing.assert_close(tu.exp_map_to_quat(torch.zeros(3)), q(0, 0, 0, 1))
    # 2π + 0.5 about x is the same rotation as 0.5 about x
    a = tu.exp_map_to_quat(torch.tensor([2 * math.pi + 0.5, 0, 0]))
    b = tu.exp_map_to_quat(torch.tensor([0.5, 0, 0]))
    torch.testing.assert_close(tu.quat_pos(a), tu.quat_pos(b), atol=1e-5, rtol=0)


def test_axis_angle_round_trip():
    axis, angle = tu.quat_to_axis_angle(tu.quat_from_axis_angle(torch.tensor([0.0, 3.0, 4.0]), torch.tensor(1.2)))
    torch.testing.assert_close(axis, torch.tensor([0.0, 0.6, 0.8]))
    torch.testing.assert_close(angle, torch.tensor(1.2))


def test_tan_norm_of_identity_and_rotation():
    torch.testing.assert_close(tu.quat_to_tan_norm(q(0, 0, 0, 1)), torch.tensor([1.0, 0, 0, 0, 0, 1]))
    ry90 = q(0, math.sin(math.pi / 4), 0, math.cos(math.pi / 4))  # x → -z, z → x
    torch.testing.assert_close(tu.quat_to_tan_norm(ry90), torch.tensor([0.0, 0, -1, 1, 0, 0]), atol=1e-6, rtol=0)


def test_tan_norm_is_the_rotated_x_and_z_axes():
    rot = tu.quat_normalize(torch.randn(5, 3, 4, generator=torch.Generator().manual_seed(0)))
    x, z = torch.tensor([1.0, 0.0, 0.0]).expand(5, 3, 3), torch.tensor([0.0, 0.0, 1.0]).expand(5, 3, 3)
    expected = torch.cat([tu.quat_rotate(rot, x), tu.quat_rotate(rot, z)], dim=-1)
    torch.testing.assert_close(tu.quat_to_tan_norm(rot), expected, atol=1e-6, rtol=0)


def test_heading_ignores_tilt():
    yaw = tu.quat_from_axis_angle(torch.tensor([0.0, 0, 1]), torch.tensor(0.7))
    tilt = tu.quat_from_axis_angle(torch.tensor([0.0, 1, 0]), torch.tensor(0.3))
    torch.testing.assert_close(tu.calc_heading(tu.quat_mul(yaw, tilt)), torch.tensor(0.7), atol=1e-6, rtol=0)
    inv = tu.calc_heading_quat_inv(yaw)
    torch.testing.assert_close(tu.quat_pos(tu.quat_mul(inv, yaw)), q(0, 0, 0, 1), atol=1e-6, rtol=0)


def test_slerp_midpoint_and_ends():
    q0 = q(0, 0, 0, 1)
    q1 = tu.quat_from_axis_angle(torch.tensor([0.0, 0, 1]), torch.tensor(1.0))
    mid = tu.slerp(q0, q1, torch.tensor(0.5))
    torch.testing.assert_close(mid, tu.quat_from_axis_angle(torch.tensor([0.0, 0, 1]), torch.tensor(0.5)))
    torch.testing.assert_close(tu.slerp(q0, q1, torch.tensor(0.0)), q0)
    torch.testing.assert_close(tu.slerp(q0, q1, torch.tensor(1.0)), q1, atol=1e-6, rtol=0)
    # shortest path: -q1 is the same rotation, the result must be too
    torch.testing.assert_close(tu.quat_pos(tu.slerp(q0, -q1, torch.tensor(0.5))), mid, atol=1e-6, rtol=0)


def test_quat_diff_angle():
    a = tu.quat_from_axis_angle(torch.tensor([1.0, 0, 0]), torch.tensor(0.2))
    b = tu.quat_from_axis_angle(torch.tensor([1.0, 0, 0]), torch.tensor(-0.5))
    torch.testing.assert_close(tu.quat_diff_angle(a, b), torch.tensor(0.7), atol=1e-6, rtol=0)
    torch.testing.assert_close(tu.quat_diff_angle(3.0 * a, -0.5 * b), torch.tensor(0.7), atol=1e-6, rtol=0)
    # Against the angle of the relative quaternion built explicitly, on random pairs (and broadcast).
    g = torch.Generator().manual_seed(3)
    q0, q1 = (tu.quat_normalize(torch.randn(200, 4, generator=g)) for _ in range(2))
    expected = tu.quat_angle(tu.quat_mul(q1, tu.quat_conjugate(q0)))
    torch.testing.assert_close(tu.quat_diff_angle(q0, q1), expected, atol=2e-6, rtol=0)
    assert tu.quat_diff_angle(q0[:3, None], q1[None, :5]).shape == (3, 5)


def test_matrix_matches_rotate():
    g = torch.Generator().manual_seed(1)
    qs = tu.quat_normalize(torch.randn(50, 4, generator=g))
    v = torch.randn(50, 3, generator=g)
    torch.testing.assert_close(
        (tu.quat_to_matrix(qs) @ v.unsqueeze(-1)).squeeze(-1), tu.quat_rotate(qs, v), atol=1e-5, rtol=0
    )


def test_tan_norm_to_quat_inverts_quat_to_tan_norm_at_any_angle() -> None:
    """Shepperd's pivot keeps half-turns (an axis from a vanishing skew part elsewhere) as exact as the rest."""
    q = tu.quat_pos(tu.quat_normalize(torch.randn(4096, 4, dtype=torch.float64)))
    half_turns = tu.quat_from_axis_angle(torch.randn(64, 3, dtype=torch.float64), torch.full((64,), math.pi))
    q = torch.cat([q, tu.quat_pos(half_turns), tu.quat_identity((1,)).double()])
    back = tu.tan_norm_to_quat(tu.quat_to_tan_norm(q))
    assert float(tu.quat_diff_angle(back, q).max()) < 1e-6
    torch.testing.assert_close(back.norm(dim=-1), torch.ones(len(q), dtype=torch.float64))
    m = tu.quat_to_matrix(q)
    torch.testing.assert_close(tu.quat_to_matrix(tu.matrix_to_quat(m)), m)
