"""DeepMimic's imitation reward, one small function per term, the reference's terms and formula.

Each term is exp(−scale · error) ∈ (0, 1], exactly 1 when the character matches the reference; the
reward is Σ weight · term. Shapes: N envs, J bodies, D DoFs, K key bodies.
"""

from __future__ import annotations

import torch

from mimickit.util import torch_util as tu

TERM_NAMES = ("pose", "vel", "root_pose", "root_vel", "key_pos")


def pose_error(joint_rot: torch.Tensor, ref_joint_rot: torch.Tensor, joint_err_w: torch.Tensor) -> torch.Tensor:
    """Σ_j w_j θ_j² over joint rotations [N, J-1, 4] → [N]."""
    angle = tu.quat_diff_angle(joint_rot, ref_joint_rot)
    return (joint_err_w * angle * angle).sum(-1)


def vel_error(dof_vel: torch.Tensor, ref_dof_vel: torch.Tensor, dof_err_w: torch.Tensor) -> torch.Tensor:
    """Σ_d w_d (q̇_ref − q̇)² over [N, D] → [N]."""
    diff = ref_dof_vel - dof_vel
    return (dof_err_w * diff * diff).sum(-1)


def root_pos_error(
    root_pos: torch.Tensor, ref_root_pos: torch.Tensor, track_root: bool, root_height: bool
) -> torch.Tensor:
    diff = ref_root_pos - root_pos
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


def compute_reward_terms(
    sim: dict[str, torch.Tensor],
    ref: dict[str, torch.Tensor],
    joint_err_w: torch.Tensor,
    dof_err_w: torch.Tensor,
    scales: dict[str, float],
    track_root: bool,
    root_height_obs: bool,
) -> dict[str, torch.Tensor]:
    """Unweighted terms [N] from states with keys root_pos, root_rot, root_vel, root_ang_vel,
    joint_rot, dof_vel, key_pos (world key body positions [N, K, 3])."""
    key_rel = sim["key_pos"] - sim["root_pos"].unsqueeze(-2)
    ref_key_rel = ref["key_pos"] - ref["root_pos"].unsqueeze(-2)
    rot, vel, ang_vel = sim["root_rot"], sim["root_vel"], sim["root_ang_vel"]
    ref_rot, ref_vel, ref_ang_vel = ref["root_rot"], ref["root_vel"], ref["root_ang_vel"]
    if not track_root:
        rot, vel, ang_vel, key_rel = _in_heading_frame(rot, vel, ang_vel, key_rel)
        ref_rot, ref_vel, ref_ang_vel, ref_key_rel = _in_heading_frame(ref_rot, ref_vel, ref_ang_vel, ref_key_rel)
    errors = {
        "pose": pose_error(sim["joint_rot"], ref["joint_rot"], joint_err_w),  # the angle ignores |q|
        "vel": vel_error(sim["dof_vel"], ref["dof_vel"], dof_err_w),
        "root_pose": root_pos_error(sim["root_pos"], ref["root_pos"], track_root, root_height_obs)
        + 0.1 * root_rot_error(rot, ref_rot),
        "root_vel": sq_norm(vel, ref_vel) + 0.1 * sq_norm(ang_vel, ref_ang_vel),
        "key_pos": key_pos_error(key_rel, ref_key_rel),
    }
    return {name: torch.exp(-scales[name] * err) for name, err in errors.items()}


def tracking_errors(
    sim: dict[str, torch.Tensor], ref: dict[str, torch.Tensor], dof_joint_ids: torch.Tensor
) -> dict[str, torch.Tensor]:
    """Per-env tracking errors [N]: the reference code's seven (metres, radians and their
    rates, means over bodies/DoFs), then the paper's two (`paper_errors`). `dof_joint_ids` [D]: the
    non-root joint (0..J-2) owning each DoF (`KinCharModel.dof_joint_ids`)."""
    root_err = torch.linalg.norm(sim["root_pos"] - ref["root_pos"], dim=-1)
    body_rel = sim["body_pos"] - sim["root_pos"].unsqueeze(-2)
    ref_body_rel = ref["body_pos"] - ref["root_pos"].unsqueeze(-2)
    rel_err = torch.linalg.norm(body_rel - ref_body_rel, dim=-1)  # [N, J], 0 for the root itself
    return {
        "root_pos_err": root_err,
        "root_rot_err": tu.quat_diff_angle(sim["root_rot"], ref["root_rot"]),
        "body_pos_err": rel_err.mean(-1),
        "body_rot_err": tu.quat_diff_angle(sim["body_rot"], ref["body_rot"]).mean(-1),
        "dof_vel_err": (sim["dof_vel"] - ref["dof_vel"]).abs().mean(-1),
        "root_vel_err": (sim["root_vel"] - ref["root_vel"]).abs().mean(-1),
        "root_ang_vel_err": (sim["root_ang_vel"] - ref["root_ang_vel"]).abs().mean(-1),
        **paper_errors(sim, ref, rel_err, root_err, dof_joint_ids),
    }


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
    rel_err: torch.Tensor,
    root_err: torch.Tensor,
    dof_joint_ids: torch.Tensor,
) -> dict[str, torch.Tensor]:
    """The paper's position and DoF velocity errors [N], each a mean over N_joint + 1 = J terms (the J-1
    non-root joints, fixed ones included, plus the root), where the reference code's body_pos_err
    leaves out the root's global position:
    * paper_pos_err_m = (Σ_j |Δ(x_j − x_root)| + |Δx_root|) / J, metres;
    * paper_dof_vel_err = (Σ_j |Δq̇_j| + |Δω_root|) / J, rad/s: |Δq̇_j| the L2 norm over joint j's DoFs of
      its local angular-velocity error (1 value for a hinge, 3 for a ball joint, 0 for a fixed one),
      Δω_root the error of the root's angular velocity in its own (local) frame.
    rel_err [N, J] are the root-relative body position errors (column 0 the root's, 0), root_err [N]."""
    num_joints = rel_err.shape[-1]
    sq = (sim["dof_vel"] - ref["dof_vel"]).square()
    per_joint = sq.new_zeros(sq.shape[0], num_joints - 1).index_add_(1, dof_joint_ids, sq).sqrt()
    root_w = tu.quat_rotate_inverse(sim["root_rot"], sim["root_ang_vel"])
    ref_root_w = tu.quat_rotate_inverse(ref["root_rot"], ref["root_ang_vel"])
    return {
        "paper_pos_err_m": (rel_err[..., 1:].sum(-1) + root_err) / num_joints,
        "paper_dof_vel_err": (per_joint.sum(-1) + torch.linalg.norm(root_w - ref_root_w, dim=-1)) / num_joints,
    }
