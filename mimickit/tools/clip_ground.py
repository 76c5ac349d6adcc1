"""How far a clip's feet go below the ground plane when played on a character."""

from __future__ import annotations

import torch

from mimickit.anim.char_geometry import body_surface_points, lowest_point_z
from mimickit.anim.kin_char_model import KinCharModel
from mimickit.anim.motion import Motion
from mimickit.util import torch_util as tu


def clip_body_poses(char: KinCharModel, motion: Motion) -> tuple[torch.Tensor, torch.Tensor]:
    """Kinematic body positions [T, J, 3] and rotations [T, J, 4] of every frame."""
    frames = torch.as_tensor(motion.frames, dtype=torch.float32)
    return char.forward_kinematics(frames[:, :3], tu.exp_map_to_quat(frames[:, 3:6]), char.dof_to_rot(frames[:, 6:]))


def lowest_foot_z(char: KinCharModel, motion: Motion, feet: list[str]) -> torch.Tensor:
    """Lowest z [T] of the foot geoms in every frame (negative: below the ground)."""
    ids, pts = body_surface_points(char, feet)
    pos, rot = clip_body_poses(char, motion)
    return lowest_point_z(char, ids, pts, pos, rot)
