"""Observation features of a character, as pure functions of batched state, laid out
as the reference's (so its checkpoints' observation normalisers fit).

Shapes: N envs, J bodies (root included), D DoFs, K key bodies.
"""

from __future__ import annotations

import torch

from mimickit.util import torch_util as tu


def compute_char_obs(
    root_pos: torch.Tensor,
    root_rot: torch.Tensor,
    root_vel: torch.Tensor,
    root_ang_vel: torch.Tensor,
    joint_rot: torch.Tensor,
    dof_vel: torch.Tensor,
    key_pos: torch.Tensor,
    global_obs: bool,
    root_height_obs: bool,
) -> torch.Tensor:
    """[N, (1) + 6 + 3 + 3 + 6(J-1) + D + 3K] from root [N,3|4], joint_rot [N,J-1,4], dof_vel [N,D],
    key_pos [N,K,3]. Local observations are expressed in the root's heading frame."""
    parts = []
    if root_height_obs:
        parts.append(root_pos[..., 2:3])
    if global_obs:
        rot, vel, ang_vel = root_rot, root_vel, root_ang_vel
        key = key_pos - root_pos.unsqueeze(-2)
    else:
        heading_inv = tu.calc_heading_quat_inv(root_rot)
        rot = tu.quat_mul(heading_inv, root_rot)
        vel = tu.quat_rotate(heading_inv, root_vel)
        ang_vel = tu.quat_rotate(heading_inv, root_ang_vel)
        key = tu.quat_rotate(heading_inv.unsqueeze(-2), key_pos - root_pos.unsqueeze(-2))
    # One tangent-normal call for the root and the joints: it is a few dozen small ops whatever the size.
    tan_norm = tu.quat_to_tan_norm(torch.cat([rot.unsqueeze(-2), joint_rot], dim=-2))
    parts += [tan_norm[..., 0, :], vel, ang_vel]
    parts.append(tan_norm[..., 1:, :].flatten(-2))
    parts.append(dof_vel)
    parts.append(key.flatten(-2))
    return torch.cat(parts, dim=-1)


def compute_phase_obs(phase: torch.Tensor, num_encoding: int) -> torch.Tensor:
    """[N, 1 + 2K]: the phase and its sin/cos at frequencies 2π·2^k."""
    parts = [phase.unsqueeze(-1)]
    if num_encoding > 0:
        k = 2.0 * torch.pi * (2.0 ** torch.arange(num_encoding, device=phase.device, dtype=phase.dtype))
        angle = phase.unsqueeze(-1) * k
        parts += [torch.sin(angle), torch.cos(angle)]
    return torch.cat(parts, dim=-1)


def compute_tar_obs(
    ref_root_pos: torch.Tensor,
    ref_root_rot: torch.Tensor,
    tar_root_pos: torch.Tensor,
    tar_root_rot: torch.Tensor,
    tar_joint_rot: torch.Tensor,
    tar_key_pos: torch.Tensor,
    global_obs: bool,
    root_height_obs: bool,
) -> torch.Tensor:
    """Target frames S steps ahead: tar_root_pos [N,S,3], tar_root_rot [N,S,4], tar_joint_rot [N,S,J-1,4],
    tar_key_pos [N,S,K,3] relative to the reference root ref_root_pos [N,3] / ref_root_rot [N,4] →
    [N, S·(3|2 + 6 + 6(J-1) + 3K)]."""
    pose = compute_tar_pose_obs(ref_root_rot, tar_root_pos, tar_root_rot, tar_joint_rot, tar_key_pos, global_obs)
    return join_tar_obs(ref_root_pos, ref_root_rot, tar_root_pos, pose, global_obs, root_height_obs)


def compute_tar_pose_obs(
    ref_root_rot: torch.Tensor,
    tar_root_pos: torch.Tensor,
    tar_root_rot: torch.Tensor,
    tar_joint_rot: torch.Tensor,
    tar_key_pos: torch.Tensor,
    global_obs: bool,
) -> torch.Tensor:
    """The target features that do not depend on the reference root's position, [N, S, 6 + 6(J-1) + 3K]:
    with global observations they depend on the clip alone, so an env can compute them ahead."""
    key = tar_key_pos - tar_root_pos.unsqueeze(-2)
    rot = tar_root_rot
    if not global_obs:
        heading_inv = tu.calc_heading_quat_inv(ref_root_rot).unsqueeze(-2)  # [N,1,4]
        rot = tu.quat_mul(heading_inv.expand_as(rot), rot)
        key = tu.quat_rotate(heading_inv.unsqueeze(-2), key)
    tan_norm = tu.quat_to_tan_norm(torch.cat([rot.unsqueeze(-2), tar_joint_rot], dim=-2))  # root, then joints
    return torch.cat([tan_norm.flatten(-2), key.flatten(-2)], dim=-1)


def join_tar_obs(
    ref_root_pos: torch.Tensor,
    ref_root_rot: torch.Tensor,
    tar_root_pos: torch.Tensor,
    pose_obs: torch.Tensor,
    global_obs: bool,
    root_height_obs: bool,
) -> torch.Tensor:
    """The target obs from `compute_tar_pose_obs` and the targets' root positions relative to the
    reference root."""
    rel = tar_root_pos - ref_root_pos.unsqueeze(-2)
    if not global_obs:
        rel = tu.quat_rotate(tu.calc_heading_quat_inv(ref_root_rot).unsqueeze(-2), rel)
    rel = torch.cat([rel[..., :2], tar_root_pos[..., 2:3]], dim=-1) if root_height_obs else rel[..., :2]
    return torch.cat([rel, pose_obs], dim=-1).flatten(-2)
