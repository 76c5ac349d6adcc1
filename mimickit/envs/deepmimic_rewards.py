"""DeepMimic's imitation reward, one small function per term, the reference's terms and formula.

Each term is exp(−scale · error) ∈ (0, 1], exactly 1 when the character matches the reference; the
reward is Σ weight · term. Shapes: N envs, J bodies, D DoFs, K key bodies.

A step computes the reward terms and the tracking errors together: the sim − reference differences both
read are taken once (`Deltas`), and the terms and errors come out stacked ([5, N], [9, N]) for the env to
store with one copy each. At 256 envs a torch op costs more in dispatch than in arithmetic, so fewer,
larger ops make this cheaper. Every value is the same elementwise arithmetic as term by term, bit for bit
at any N: only ops whose result does not depend on where an element sits are fused. torch's atan2 is
not one (the vectorised loop's scalar tail rounds differently), so each rotation field keeps its own
`quat_diff_angle` call.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from mimickit.util import torch_util as tu
from mimickit.util.config import ConfigModel

TERM_NAMES = ("pose", "vel", "root_pose", "root_vel", "key_pos")
"""The terms, in the order of `compute_reward_errors`' rows; each has its two fields below."""
TRACKING_NAMES = (
    "root_pos_err", "root_rot_err", "body_pos_err", "body_rot_err", "dof_vel_err", "root_vel_err",
    "root_ang_vel_err", "paper_pos_err_m", "paper_dof_vel_err",
)  # fmt: skip


class DeepMimicRewardConfig(ConfigModel):
    """Each term's weight and scale, `reward_<term>_w` and `reward_<term>_scale` (the reference's yaml
    fields): the reward is Σ w · exp(−scale · error). A new term's two fields go here, beside its error."""

    reward_pose_w: float
    reward_vel_w: float
    reward_root_pose_w: float
    reward_root_vel_w: float
    reward_key_pos_w: float
    reward_pose_scale: float
    reward_vel_scale: float
    reward_root_pose_scale: float
    reward_root_vel_scale: float
    reward_key_pos_scale: float


@dataclass(frozen=True)
class Deltas:
    """Sim − reference differences of one batch of states, shared by the reward terms and the tracking
    errors: root_pos [N, 3], body_rel [N, J, 3] (Δ of the root-relative body positions, 0 for the root),
    dof_vel [N, D], root_vel and root_ang_vel [N, 3], and rotation angles in [0, π]: root [N], body [N, J]
    and joint [N, J-1] (None when the states hold no joint_rot)."""

    root_pos: torch.Tensor
    body_rel: torch.Tensor
    dof_vel: torch.Tensor
    root_vel: torch.Tensor
    root_ang_vel: torch.Tensor
    root_angle: torch.Tensor
    body_angle: torch.Tensor
    joint_angle: torch.Tensor | None


def state_deltas(sim: dict[str, torch.Tensor], ref: dict[str, torch.Tensor]) -> Deltas:
    """The differences of states with keys root_pos, root_rot, root_vel, root_ang_vel, dof_vel, body_pos,
    body_rot (and joint_rot for the pose term)."""
    body_rel = sim["body_pos"] - sim["root_pos"].unsqueeze(-2)
    ref_body_rel = ref["body_pos"] - ref["root_pos"].unsqueeze(-2)
    joints = "joint_rot" in sim and "joint_rot" in ref
    rot_keys = ("root_rot", "body_rot", "joint_rot") if joints else ("root_rot", "body_rot")
    angles = _diff_angles(sim, ref, rot_keys)
    return Deltas(
        root_pos=sim["root_pos"] - ref["root_pos"],
        body_rel=body_rel - ref_body_rel,
        dof_vel=sim["dof_vel"] - ref["dof_vel"],
        root_vel=sim["root_vel"] - ref["root_vel"],
        root_ang_vel=sim["root_ang_vel"] - ref["root_ang_vel"],
        root_angle=angles[0].squeeze(-1),
        body_angle=angles[1],
        joint_angle=angles[2] if joints else None,
    )


def _diff_angles(
    sim: dict[str, torch.Tensor], ref: dict[str, torch.Tensor], keys: tuple[str, ...]
) -> tuple[torch.Tensor, ...]:
    """`quat_diff_angle` of each key's quaternions ([N, 4] or [N, M, 4]): [N, 1] or [N, M] per key (one
    call per key: see the module docstring)."""
    return tuple(tu.quat_diff_angle(_quat_rows(sim[k]), _quat_rows(ref[k])) for k in keys)


def _quat_rows(q: torch.Tensor) -> torch.Tensor:
    """[N, 4] as [N, 1, 4]; [N, M, 4] as it is."""
    return q.unsqueeze(-2) if q.dim() == 2 else q


def weighted_sq_sum(x: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Σ_i w_i x_i² over the last dim: the pose error from joint angles, the velocity error from DoF
    velocity differences (the sign of x does not change the rounding)."""
    return (w * x * x).sum(-1)


def root_pos_sq_error(diff: torch.Tensor, track_root: bool, root_height: bool) -> torch.Tensor:
    """|Δroot|² [N] of the root position difference [N, 3]: x, y only when the root is tracked, z only
    with root height observations."""
    if not track_root:
        diff = torch.cat([torch.zeros_like(diff[..., :2]), diff[..., 2:]], dim=-1)
    if not root_height:
        diff = torch.cat([diff[..., :2], torch.zeros_like(diff[..., 2:])], dim=-1)
    return (diff * diff).sum(-1)


def root_rot_error(root_rot: torch.Tensor, ref_root_rot: torch.Tensor) -> torch.Tensor:
    angle = tu.quat_diff_angle(root_rot, ref_root_rot)
    return angle * angle


def sq_norm(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    d = a - b
    return (d * d).sum(-1)


def key_pos_error(key_rel: torch.Tensor, ref_key_rel: torch.Tensor) -> torch.Tensor:
    """Σ_k |Δk|² over root-relative key positions [N, K, 3] → [N]."""
    return sq_norm(key_rel, ref_key_rel).sum(-1)


def _in_heading_frame(root_rot: torch.Tensor, *vecs: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """Express the root rotation and vectors (each [N, 3] or [N, K, 3]) in the root's heading frame."""
    h = tu.calc_heading_quat_inv(root_rot)
    out = [tu.quat_mul(h, root_rot)]
    for v in vecs:
        out.append(tu.quat_rotate(h.unsqueeze(-2), v) if v.dim() == 3 else tu.quat_rotate(h, v))
    return tuple(out)


def compute_reward_errors(
    sim: dict[str, torch.Tensor],
    ref: dict[str, torch.Tensor],
    d: Deltas,
    key_ids: torch.Tensor,
    joint_err_w: torch.Tensor,
    dof_err_w: torch.Tensor,
    track_root: bool,
    root_height_obs: bool,
) -> torch.Tensor:
    """The five terms' errors [5, N] in TERM_NAMES order, from states with keys root_pos, root_rot,
    root_vel, root_ang_vel, joint_rot, dof_vel, body_pos and their `Deltas` (with joint angles); key_ids
    [K]: the key bodies. Untracked roots compare velocities and key positions in each one's heading
    frame."""
    if track_root:
        root_rot_err = d.root_angle * d.root_angle
        root_vel_err = (d.root_vel * d.root_vel).sum(-1) + 0.1 * (d.root_ang_vel * d.root_ang_vel).sum(-1)
        key_diff = d.body_rel.index_select(-2, key_ids)
        key_err = (key_diff * key_diff).sum(-1).sum(-1)
    else:
        root_rot_err, root_vel_err, key_err = _heading_frame_errors(sim, ref, key_ids)
    assert d.joint_angle is not None, "the pose term needs joint_rot in both states"
    errors = (
        weighted_sq_sum(d.joint_angle, joint_err_w),  # the angle ignores |q|
        weighted_sq_sum(d.dof_vel, dof_err_w),
        root_pos_sq_error(d.root_pos, track_root, root_height_obs) + 0.1 * root_rot_err,
        root_vel_err,
        key_err,
    )
    return torch.stack(errors)


def _heading_frame_errors(
    sim: dict[str, torch.Tensor], ref: dict[str, torch.Tensor], key_ids: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The root rotation, root velocity and key position errors [N] of an untracked root: each state's
    root rotation, velocities and root-relative key positions expressed in its own heading frame."""
    key_rel = sim["body_pos"].index_select(-2, key_ids) - sim["root_pos"].unsqueeze(-2)
    ref_key_rel = ref["body_pos"].index_select(-2, key_ids) - ref["root_pos"].unsqueeze(-2)
    rot, vel, ang_vel, key_rel = _in_heading_frame(sim["root_rot"], sim["root_vel"], sim["root_ang_vel"], key_rel)
    ref_rot, ref_vel, ref_ang_vel, ref_key_rel = _in_heading_frame(
        ref["root_rot"], ref["root_vel"], ref["root_ang_vel"], ref_key_rel
    )
    root_vel_err = sq_norm(vel, ref_vel) + 0.1 * sq_norm(ang_vel, ref_ang_vel)
    return root_rot_error(rot, ref_rot), root_vel_err, key_pos_error(key_rel, ref_key_rel)


def reward_terms(errors: torch.Tensor, neg_scales: torch.Tensor) -> torch.Tensor:
    """Terms exp(−scale · error) [5, N] from errors [5, N] and −scales [5, 1]."""
    return torch.exp(errors * neg_scales)


def tracking_errors(
    sim: dict[str, torch.Tensor], ref: dict[str, torch.Tensor], dof_joint_ids: torch.Tensor
) -> dict[str, torch.Tensor]:
    """Per-env tracking errors [N]: the reference code's seven (metres, radians and their
    rates, means over bodies/DoFs), then the paper's two (`paper_errors`). `dof_joint_ids` [D]: the
    non-root joint (0..J-2) owning each DoF (`KinCharModel.dof_joint_ids`)."""
    stacked = stacked_tracking_errors(sim, ref, state_deltas(sim, ref), dof_joint_ids)
    return dict(zip(TRACKING_NAMES, stacked.unbind(0), strict=True))


def stacked_tracking_errors(
    sim: dict[str, torch.Tensor], ref: dict[str, torch.Tensor], d: Deltas, dof_joint_ids: torch.Tensor
) -> torch.Tensor:
    """`tracking_errors` from the states' `Deltas`, stacked [9, N] in TRACKING_NAMES order."""
    root_err = torch.linalg.norm(d.root_pos, dim=-1)
    rel_err = torch.linalg.norm(d.body_rel, dim=-1)  # [N, J], 0 for the root itself
    errors = (
        root_err,
        d.root_angle,
        rel_err.mean(-1),
        d.body_angle.mean(-1),
        d.dof_vel.abs().mean(-1),
        d.root_vel.abs().mean(-1),
        d.root_ang_vel.abs().mean(-1),
        *paper_errors(sim, ref, d, rel_err, root_err, dof_joint_ids),
    )
    return torch.stack(errors)


def body_pos_errors(sim: dict[str, torch.Tensor], ref: dict[str, torch.Tensor]) -> torch.Tensor:
    """Per-body position errors [N, J] in metres, the paper's position error body by body: column 0 the
    root's global |Δx_root|, column j the root-relative |Δ(x_j − x_root)| (global axes, not the heading
    frame); their mean over J is `paper_pos_err_m`. States with root_pos [N, 3] and body_pos [N, J, 3]."""
    root_err = torch.linalg.norm(sim["root_pos"] - ref["root_pos"], dim=-1)
    body_rel = sim["body_pos"] - sim["root_pos"].unsqueeze(-2)
    ref_body_rel = ref["body_pos"] - ref["root_pos"].unsqueeze(-2)
    rel_err = torch.linalg.norm(body_rel - ref_body_rel, dim=-1)
    return torch.cat([root_err.unsqueeze(-1), rel_err[..., 1:]], dim=-1)


def paper_errors(
    sim: dict[str, torch.Tensor],
    ref: dict[str, torch.Tensor],
    d: Deltas,
    rel_err: torch.Tensor,
    root_err: torch.Tensor,
    dof_joint_ids: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The paper's position and DoF velocity errors [N], each a mean over N_joint + 1 = J terms (the J-1
    non-root joints, fixed ones included, plus the root), where the reference code's body_pos_err
    leaves out the root's global position:
    * paper_pos_err_m = (Σ_j |Δ(x_j − x_root)| + |Δx_root|) / J, metres;
    * paper_dof_vel_err = (Σ_j |Δq̇_j| + |Δω_root|) / J, rad/s: |Δq̇_j| the L2 norm over joint j's DoFs of
      its local angular-velocity error (1 value for a hinge, 3 for a ball joint, 0 for a fixed one),
      Δω_root the error of the root's angular velocity in its own (local) frame.
    rel_err [N, J] are the root-relative body position errors (column 0 the root's, 0), root_err [N]."""
    num_joints = rel_err.shape[-1]
    sq = d.dof_vel.square()
    per_joint = sq.new_zeros(sq.shape[0], num_joints - 1).index_add_(1, dof_joint_ids, sq).sqrt()
    # Both root angular velocities into their local frames with one rotation (plain arithmetic: stacking
    # the two changes no rounding).
    rot = torch.stack([sim["root_rot"], ref["root_rot"]])
    root_w, ref_root_w = tu.quat_rotate_inverse(rot, torch.stack([sim["root_ang_vel"], ref["root_ang_vel"]]))
    return (
        (rel_err[..., 1:].sum(-1) + root_err) / num_joints,
        (per_joint.sum(-1) + torch.linalg.norm(root_w - ref_root_w, dim=-1)) / num_joints,
    )
