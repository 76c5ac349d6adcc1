"""A clip posed on a character, once for all frames: what the player draws and reports.

Forward kinematics of the whole clip is one batched call (milliseconds for thousands of frames), so
playback is table look-ups. Shapes: T frames, J bodies, F feet, D DoFs.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from mimickit.anim.char_geometry import body_surface_points, lowest_point_z
from mimickit.anim.kin_char_model import JointType, KinCharModel
from mimickit.anim.mjcf_char_model import load_char_model
from mimickit.anim.motion import LoopMode, Motion
from mimickit.tools.motion_report import check_frame_dim
from mimickit.util import torch_util as tu
from mimickit.util.warn import collect_warnings
from studio.parsing import read_motion

CONTACT_HEIGHT = 0.02  # a foot whose lowest point is this close to the ground counts as in contact
_FOOT = re.compile(r"foot|toe|ankle", re.IGNORECASE)


@dataclass
class ClipPose:
    path: Path
    char_path: Path
    motion: Motion
    char: KinCharModel
    body_pos: np.ndarray  # [T, J, 3] world positions
    body_rot: np.ndarray  # [T, J, 4] world rotations, xyzw
    body_xmat: np.ndarray  # [T, J, 3, 3] the same as matrices (what the viewer takes)
    feet: list[str]  # names of the F foot bodies
    foot_low_z: np.ndarray  # [T, F] lowest point of each foot's collision shapes

    @property
    def num_frames(self) -> int:
        return self.motion.num_frames

    @property
    def fps(self) -> float:
        return self.motion.fps

    @property
    def root_pos(self) -> np.ndarray:
        """[T, 3]"""
        return self.body_pos[:, 0]

    def contacts(self, frame: int) -> np.ndarray:
        """[F] bool: which feet touch the ground at `frame`."""
        return self.foot_low_z[frame] <= CONTACT_HEIGHT

    def joint_values(self, frame: int) -> list[tuple[str, list[float]]]:
        """(joint name, its DoF values in rad) per non-root joint with DoFs, at `frame`."""
        dofs = self.motion.frames[frame, 6:]
        out = []
        for joint in self.char.joints[1:]:
            if joint.type in (JointType.HINGE, JointType.SPHERICAL):
                out.append((joint.name, dofs[joint.dof_idx : joint.dof_idx + joint.dof_dim].tolist()))
        return out


def pose_clip(clip_path: Path, char_path: Path) -> ClipPose:
    """Load a clip and a character and pose every frame; MimicKitError when they do not fit."""
    with collect_warnings():  # NaN columns read as 0 are reported by the library panel
        motion = read_motion(clip_path)  # a user's file: with the guarded loader's budget
        char = load_char_model(char_path)
    check_frame_dim(motion, char, clip_path)
    return pose_motion(clip_path, char_path, motion, char)


def default_pose(char_path: Path) -> ClipPose:
    """The character in its MJCF default pose (every DoF 0, root unrotated) as a one-frame clip, lifted
    so that its lowest collision point touches the ground; MimicKitError when the MJCF does not load."""
    with collect_warnings():  # the library panel reports what the MJCF lacks
        char = load_char_model(char_path)
        ids, pts = body_surface_points(char, char.get_body_names())
    frame = np.zeros((1, 6 + char.get_dof_size()), dtype=np.float32)
    frame[0, :3] = char.local_pos[0].numpy()
    if len(ids):
        pos, rot = char.forward_kinematics(
            torch.from_numpy(frame[:, :3]),
            tu.exp_map_to_quat(torch.zeros(1, 3)),
            char.dof_to_rot(torch.from_numpy(frame[:, 6:])),
        )
        frame[0, 2] -= float(lowest_point_z(char, ids, pts, pos, rot)[0])
    return pose_motion(char_path, char_path, Motion(LoopMode.CLAMP, 30.0, frame), char)


def pose_motion(clip_path: Path, char_path: Path, motion: Motion, char: KinCharModel) -> ClipPose:
    """Every frame of `motion` posed on `char` (their widths already checked)."""
    frames = torch.from_numpy(motion.frames)
    root_rot = tu.exp_map_to_quat(frames[:, 3:6])
    joint_rot = char.dof_to_rot(frames[:, 6:])
    with torch.no_grad():
        body_pos, body_rot = char.forward_kinematics(frames[:, :3], root_rot, joint_rot)
    feet = foot_bodies(char)
    low = feet_low_z(char, feet, body_pos, body_rot)
    xmat = tu.quat_to_matrix(body_rot).numpy()
    return ClipPose(clip_path, char_path, motion, char, body_pos.numpy(), body_rot.numpy(), xmat, feet, low)


def feet_low_z(char: KinCharModel, feet: list[str], body_pos: torch.Tensor, body_rot: torch.Tensor) -> np.ndarray:
    """[T, F] lowest point of each foot's collision shapes, given posed bodies body_pos [T, J, 3] and
    body_rot [T, J, 4] (xyzw) in the character's body order."""
    low = np.zeros((body_pos.shape[0], len(feet)), dtype=np.float32)
    for i, name in enumerate(feet):
        with collect_warnings():  # it re-reads the MJCF: the warnings its load gave already
            ids, pts = body_surface_points(char, [name])
        if len(ids):
            low[:, i] = lowest_point_z(char, ids, pts, body_pos, body_rot).numpy()
        else:  # a foot without collision shapes: its origin stands in
            low[:, i] = body_pos[:, char.get_body_id(name), 2].numpy()
    return low


def foot_bodies(char: KinCharModel) -> list[str]:
    """Bodies named like feet (foot, toe, ankle), keeping the last of each chain (toe over ankle)."""
    names = char.get_body_names()
    matched = [i for i, n in enumerate(names) if _FOOT.search(n)]
    has_matched_child = {char.get_parent_id(i) for i in matched}
    return [names[i] for i in matched if i not in has_matched_child]
