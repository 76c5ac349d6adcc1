"""Batched rotation math in torch.

Quaternions are (x, y, z, w) with w last, as everywhere in the framework; MuJoCo's w-first order is
converted only at the engine boundary (`quat_to_wxyz`, `quat_from_wxyz`). Every function accepts any
leading batch shape `[..., 4]` / `[..., 3]`.
"""

from __future__ import annotations

import math

import torch

_EPS = 1e-5


def quat_to_wxyz(q: torch.Tensor) -> torch.Tensor:
    return torch.cat([q[..., 3:4], q[..., 0:3]], dim=-1)


def quat_from_wxyz(q: torch.Tensor) -> torch.Tensor:
    return torch.cat([q[..., 1:4], q[..., 0:1]], dim=-1)


def quat_identity(shape: tuple[int, ...] = (), device: torch.device | str = "cpu") -> torch.Tensor:
    q = torch.zeros(*shape, 4, device=device)
    q[..., 3] = 1.0
    return q


def quat_normalize(q: torch.Tensor) -> torch.Tensor:
    return q / torch.linalg.norm(q, dim=-1, keepdim=True).clamp_min(1e-12)


def quat_pos(q: torch.Tensor) -> torch.Tensor:
    """The same rotation with w >= 0 (a canonical sign)."""
    return torch.where(q[..., 3:4] < 0, -q, q)


def quat_conjugate(q: torch.Tensor) -> torch.Tensor:
    return torch.cat([-q[..., :3], q[..., 3:]], dim=-1)


def _cross(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Cross product over the last dim with broadcasting (torch.cross wants equal ranks)."""
    if a.shape != b.shape:
        a, b = torch.broadcast_tensors(a, b)
    return torch.cross(a, b, dim=-1)


def quat_mul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product a ⊗ b: rotate by b first, then by a."""
    av, aw = a[..., :3], a[..., 3:]
    bv, bw = b[..., :3], b[..., 3:]
    # The vector form needs a handful of batched ops instead of 28 scalar-column ones: FK is hot.
    v = aw * bv + bw * av + _cross(av, bv)
    w = aw * bw - (av * bv).sum(-1, keepdim=True)
    return torch.cat([v, w], dim=-1)


def quat_rotate(q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Rotate vectors v [..., 3] by quaternions q [..., 4]."""
    qv = q[..., :3]
    w = q[..., 3:4]
    t = 2.0 * _cross(qv, v)
    return v + w * t + _cross(qv, t)


def quat_rotate_inverse(q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    return quat_rotate(quat_conjugate(q), v)


def quat_from_axis_angle(axis: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """axis [..., 3] (normalised here), angle [...] in radians."""
    axis = axis / torch.linalg.norm(axis, dim=-1, keepdim=True).clamp_min(1e-12)
    half = 0.5 * angle.unsqueeze(-1)
    return torch.cat([axis * torch.sin(half), torch.cos(half)], dim=-1)


def quat_to_axis_angle(q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Unit axis [..., 3] and angle [...] in [0, π]; axis (0, 0, 1) for near-identity rotations."""
    q = quat_pos(quat_normalize(q))
    v = q[..., :3]
    sin_half = torch.linalg.norm(v, dim=-1)
    angle = 2.0 * torch.atan2(sin_half, q[..., 3])
    default = torch.zeros_like(v)
    default[..., 2] = 1.0
    small = (sin_half <= _EPS).unsqueeze(-1)
    axis = torch.where(small, default, v / sin_half.clamp_min(1e-12).unsqueeze(-1))
    angle = torch.where(sin_half <= _EPS, torch.zeros_like(angle), angle)
    return axis, angle


def quat_to_exp_map(q: torch.Tensor) -> torch.Tensor:
    axis, angle = quat_to_axis_angle(q)
    return axis * angle.unsqueeze(-1)


def exp_map_to_quat(e: torch.Tensor) -> torch.Tensor:
    """Exponential map (axis · angle) [..., 3] to a quaternion; the angle is wrapped to (−π, π]."""
    angle = torch.linalg.norm(e, dim=-1)
    axis = e / angle.clamp_min(1e-12).unsqueeze(-1)
    wrapped = torch.atan2(torch.sin(angle), torch.cos(angle))
    q = quat_from_axis_angle(axis, wrapped)
    return torch.where((wrapped.abs() <= _EPS).unsqueeze(-1), quat_identity(e.shape[:-1], e.device).to(q), q)


def quat_angle(q: torch.Tensor) -> torch.Tensor:
    """Rotation angle in [0, π] of each quaternion."""
    q = quat_pos(q)
    return 2.0 * torch.atan2(torch.linalg.norm(q[..., :3], dim=-1), q[..., 3])


def quat_diff_angle(q0: torch.Tensor, q1: torch.Tensor) -> torch.Tensor:
    """Angle in [0, π] of the rotation between q0 and q1, for any norms (only the ratio of the parts of
    q1 ⊗ q0* counts). That product is written out: its scalar part is the 4-vector dot product q0·q1 and
    its vector part w0 v1 − w1 v0 − v1 × v0 (the rewards and tracking errors take this for every joint of
    every env each step)."""
    v0, w0 = q0[..., :3], q0[..., 3:]
    v1, w1 = q1[..., :3], q1[..., 3:]
    w = (q0 * q1).sum(-1)
    v = w0 * v1 - w1 * v0 - _cross(v1, v0)
    return 2.0 * torch.atan2(torch.linalg.norm(v, dim=-1), w.abs())


def quat_to_tan_norm(q: torch.Tensor) -> torch.Tensor:
    """The 6D tangent-normal encoding: R(q)·x then R(q)·z, [..., 6] for unit q. Written as the first and
    third columns of the rotation matrix: half the time of two `quat_rotate` calls on observation-sized
    batches (it runs for every joint of every env each step)."""
    x, y, z, w = q.unbind(-1)
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz, xw, yw, zw = x * y, x * z, y * z, x * w, y * w, z * w
    columns = [1 - 2 * (yy + zz), 2 * (xy + zw), 2 * (xz - yw), 2 * (xz + yw), 2 * (yz - xw), 1 - 2 * (xx + yy)]
    return torch.stack(columns, dim=-1)


def matrix_to_quat(m: torch.Tensor) -> torch.Tensor:
    """Rotation matrices [..., 3, 3] to unit quaternions [..., 4] (xyzw, w >= 0) by Shepperd's method: of
    the four formulas, each proportional to q, the one with the largest pivot (accurate at any angle)."""
    m00, m01, m02 = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    m10, m11, m12 = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    m20, m21, m22 = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    candidates = torch.stack(
        [
            torch.stack([1 + m00 - m11 - m22, m01 + m10, m02 + m20, m21 - m12], dim=-1),  # 4x · q
            torch.stack([m01 + m10, 1 - m00 + m11 - m22, m12 + m21, m02 - m20], dim=-1),  # 4y · q
            torch.stack([m02 + m20, m12 + m21, 1 - m00 - m11 + m22, m10 - m01], dim=-1),  # 4z · q
            torch.stack([m21 - m12, m02 - m20, m10 - m01, 1 + m00 + m11 + m22], dim=-1),  # 4w · q
        ],
        dim=-2,
    )
    pivots = torch.stack([m00 - m11 - m22, m11 - m00 - m22, m22 - m00 - m11, m00 + m11 + m22], dim=-1)
    best = pivots.argmax(dim=-1)[..., None, None].expand(*pivots.shape[:-1], 1, 4)
    q = candidates.gather(-2, best).squeeze(-2)
    return quat_pos(q / torch.linalg.norm(q, dim=-1, keepdim=True).clamp_min(1e-12))


def tan_norm_to_quat(tan_norm: torch.Tensor) -> torch.Tensor:
    """The inverse of `quat_to_tan_norm`: [..., 6] (R·x, R·z) to unit quaternions [..., 4] (w >= 0). As the
    reference, the matrix is [tan, norm × tan, norm] without re-orthogonalising a generated pair."""
    tan, norm = tan_norm[..., 0:3], tan_norm[..., 3:6]
    return matrix_to_quat(torch.stack([tan, torch.linalg.cross(norm, tan), norm], dim=-1))


def calc_heading(q: torch.Tensor) -> torch.Tensor:
    """Yaw angle of the rotated x axis about world z, [...]."""
    x = torch.zeros(*q.shape[:-1], 3, dtype=q.dtype, device=q.device)
    x[..., 0] = 1.0
    d = quat_rotate(q, x)
    return torch.atan2(d[..., 1], d[..., 0])


def calc_heading_quat(q: torch.Tensor) -> torch.Tensor:
    z = torch.zeros(*q.shape[:-1], 3, dtype=q.dtype, device=q.device)
    z[..., 2] = 1.0
    return quat_from_axis_angle(z, calc_heading(q))


def calc_heading_quat_inv(q: torch.Tensor) -> torch.Tensor:
    z = torch.zeros(*q.shape[:-1], 3, dtype=q.dtype, device=q.device)
    z[..., 2] = 1.0
    return quat_from_axis_angle(z, -calc_heading(q))


def slerp(q0: torch.Tensor, q1: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Shortest-path spherical interpolation; t [...] or [..., 1] in [0, 1]."""
    if t.dim() == q0.dim() - 1:
        t = t.unsqueeze(-1)
    cos_half = (q0 * q1).sum(-1, keepdim=True)
    q1 = torch.where(cos_half < 0, -q1, q1)
    cos_half = cos_half.abs()
    half = torch.acos(cos_half.clamp(max=1.0))
    sin_half = torch.sqrt((1.0 - cos_half * cos_half).clamp_min(0.0))
    safe = sin_half.clamp_min(1e-12)
    ra = torch.sin((1.0 - t) * half) / safe
    rb = torch.sin(t * half) / safe
    out = ra * q0 + rb * q1
    # Near-parallel quaternions: the ratio is ill-conditioned, a (normalised) lerp is exact enough.
    near = sin_half < 1e-3
    out = torch.where(near, (1.0 - t) * q0 + t * q1, out)
    # Normalised in both cases: between close frames acos/sqrt in float32 leave |out| off 1 by up to
    # ~4e-5 (measured on a clip), which a state set from the frame would not share.
    out = quat_normalize(out)
    return torch.where(cos_half >= 1.0, q0, out)


def quat_to_matrix(q: torch.Tensor) -> torch.Tensor:
    x, y, z, w = quat_normalize(q).unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - z * w),
            2 * (x * z + y * w),
            2 * (x * y + z * w),
            1 - 2 * (x * x + z * z),
            2 * (y * z - x * w),
            2 * (x * z - y * w),
            2 * (y * z + x * w),
            1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(*q.shape[:-1], 3, 3)


def wrap_angle(a: torch.Tensor) -> torch.Tensor:
    return torch.remainder(a + math.pi, 2 * math.pi) - math.pi
