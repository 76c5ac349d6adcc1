"""The kinematic character: body tree, joints, DoF layout and batched forward kinematics.

Bodies are in depth-first order with the root first (index 0). Joints belong to non-root bodies:
a hinge has 1 DoF (angle about its axis), a spherical joint 3 DoF (the exponential map of the joint's
local rotation), a fixed joint none. The DoF vector of a character is the concatenation over bodies
1..J-1 in order: MimicKit's clip and action layout.

Shapes: `J` bodies (root included), `D` DoFs. Joint rotation arrays exclude the root: [..., J-1, 4].
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from pathlib import Path

import numpy as np
import torch

from mimickit.util import torch_util as tu
from mimickit.util.errors import MimicKitError


class JointType(IntEnum):
    ROOT = 0
    HINGE = 1
    SPHERICAL = 2
    FIXED = 3


DOF_DIM = {JointType.ROOT: 0, JointType.HINGE: 1, JointType.SPHERICAL: 3, JointType.FIXED: 0}


@dataclass
class Joint:
    """The joint between body `body_id` and its parent.

    Per-DoF arrays (`low`, `high`, `kp`, `kd`, `armature`, `torque_limit`) have `dof_dim` entries;
    for a spherical joint made of three MJCF hinges they are the hinges' x, y, z values.
    """

    name: str
    type: JointType
    body_id: int
    dof_idx: int
    axis: np.ndarray | None = None
    mjcf_joints: list[str] = field(default_factory=list)
    low: np.ndarray = field(default_factory=lambda: np.zeros(0))
    high: np.ndarray = field(default_factory=lambda: np.zeros(0))
    kp: np.ndarray = field(default_factory=lambda: np.zeros(0))
    kd: np.ndarray = field(default_factory=lambda: np.zeros(0))
    armature: np.ndarray = field(default_factory=lambda: np.zeros(0))
    torque_limit: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def dof_dim(self) -> int:
        return DOF_DIM[self.type]


class KinCharModel:
    """A character's kinematic tree; build one with `mimickit.anim.mjcf_char_model.load_char_model`."""

    def __init__(
        self,
        body_names: list[str],
        parent_ids: list[int],
        local_pos: np.ndarray,
        local_rot: np.ndarray,
        joints: list[Joint],
        body_mass: np.ndarray,
        source: str | Path = "",
        device: torch.device | str = "cpu",
    ) -> None:
        self.source = str(source)
        self.device = torch.device(device)
        self.body_names = list(body_names)
        self.parent_ids = list(parent_ids)
        self.joints = joints  # joints[j] belongs to body j; joints[0] is the root
        self.body_mass = np.asarray(body_mass, dtype=np.float64)
        self.local_pos = torch.as_tensor(local_pos, dtype=torch.float32, device=self.device)
        self.local_rot = torch.as_tensor(local_rot, dtype=torch.float32, device=self.device)
        self._build_index()

    # ------------------------------------------------------------------ queries
    def get_body_names(self) -> list[str]:
        return list(self.body_names)

    def get_num_joints(self) -> int:
        """J: the number of bodies, root included."""
        return len(self.body_names)

    def get_dof_size(self) -> int:
        return self.dof_size

    def get_joint(self, j: int) -> Joint:
        return self.joints[j]

    def get_parent_id(self, j: int) -> int:
        return self.parent_ids[j]

    def get_body_id(self, name: str) -> int:
        try:
            return self.body_names.index(name)
        except ValueError:
            raise MimicKitError(
                f"{self.source}: no body named '{name}' (bodies: {', '.join(self.body_names)})"
            ) from None

    def get_joint_id(self, name: str) -> int:
        return self.get_body_id(name) - 1

    def get_joint_dof_idx(self, j: int) -> int:
        return self.joints[j].dof_idx

    def get_joint_dof_dim(self, j: int) -> int:
        return self.joints[j].dof_dim

    def get_total_mass(self) -> float:
        return float(self.body_mass.sum())

    def dof_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """(low, high), each [D], in the DoF layout."""
        joints = self.joints[1:]
        return (
            np.concatenate([j.low for j in joints]) if joints else np.zeros(0),
            np.concatenate([j.high for j in joints]) if joints else np.zeros(0),
        )

    def dof_array(self, attr: str) -> np.ndarray:
        """A per-DoF joint attribute (`kp`, `kd`, `armature`, `torque_limit`) as [D] ([0] for a single rigid body)."""
        values = [getattr(j, attr) for j in self.joints[1:]]
        return np.concatenate(values).astype(np.float64) if values else np.zeros(0)

    def dof_joint_ids(self) -> np.ndarray:
        """For each DoF, the index (0..J-2) of the non-root joint that owns it."""
        return np.concatenate([np.full(j.dof_dim, i, dtype=np.int64) for i, j in enumerate(self.joints[1:])]).astype(
            np.int64
        )

    def to(self, device: torch.device | str) -> KinCharModel:
        self.device = torch.device(device)
        self.local_pos = self.local_pos.to(self.device)
        self.local_rot = self.local_rot.to(self.device)
        self._build_index()
        return self

    # ------------------------------------------------------------ conversions
    def dof_to_rot(self, dof: torch.Tensor) -> torch.Tensor:
        """DoF vectors [..., D] to local joint rotations [..., J-1, 4] (fixed joints: identity)."""
        batch = dof.shape[:-1]
        rot = tu.quat_identity((*batch, self.get_num_joints() - 1), dof.device).to(dof.dtype)
        if self._hinge_j.numel():
            angle = dof.index_select(-1, self._hinge_d)
            rot[..., self._hinge_j, :] = tu.quat_from_axis_angle(self._hinge_axis.to(dof), angle)
        if self._sph_j.numel():
            e = dof[..., self._sph_d]  # [..., S, 3]
            rot[..., self._sph_j, :] = tu.exp_map_to_quat(e)
        return rot

    def rot_to_dof(self, rot: torch.Tensor) -> torch.Tensor:
        """Local joint rotations [..., J-1, 4] to DoF vectors [..., D]."""
        batch = rot.shape[:-2]
        dof = torch.zeros(*batch, self.dof_size, dtype=rot.dtype, device=rot.device)
        if self._hinge_j.numel():
            q = tu.quat_pos(rot.index_select(-2, self._hinge_j))
            proj = (q[..., :3] * self._hinge_axis.to(rot)).sum(-1)
            dof[..., self._hinge_d] = 2.0 * torch.atan2(proj, q[..., 3])
        if self._sph_j.numel():
            dof[..., self._sph_d] = tu.quat_to_exp_map(rot.index_select(-2, self._sph_j))
        return dof

    def forward_kinematics(
        self, root_pos: torch.Tensor, root_rot: torch.Tensor, joint_rot: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """World body positions [..., J, 3] and rotations [..., J, 4] from the root and joint rotations."""
        batch = root_pos.shape[:-1]
        rot = root_rot.new_empty(*batch, self.get_num_joints(), 4)
        rot[..., 0, :] = root_rot
        local_rot, offsets, paths = self._fk_local_rot, self._fk_offsets, self._fk_paths
        if rot.dtype != local_rot.dtype:  # e.g. float64 callers: the precomputed float32 constants converted
            local_rot, offsets, paths = local_rot.to(rot.dtype), offsets.to(rot.dtype), paths.to(rot.dtype)
        local_rot = tu.quat_mul(local_rot, joint_rot)  # [..., J-1, 4]
        # Bodies of one tree depth depend only on shallower ones: one batched update per depth level.
        for ids, parents, joints in self._fk_levels:
            rot[..., ids, :] = tu.quat_mul(rot.index_select(-2, parents), local_rot.index_select(-2, joints))
        # A body's position is the root's plus its ancestors' rotated offsets: all offsets rotated at once,
        # then summed along each body's path with one matrix product (no per-level position updates).
        steps = tu.quat_rotate(rot.index_select(-2, self._fk_parents), offsets)  # [..., J-1, 3]
        pos = root_pos.unsqueeze(-2) + torch.einsum("ij,...jk->...ik", paths, steps)
        return pos, rot

    def compute_dof_vel(self, rot0: torch.Tensor, rot1: torch.Tensor, dt: float) -> torch.Tensor:
        """DoF velocities [..., D] that take joint rotations rot0 to rot1 in `dt` (local frame)."""
        delta = tu.quat_pos(tu.quat_mul(tu.quat_conjugate(rot0), rot1))
        e = tu.quat_to_exp_map(delta)  # [..., J-1, 3]
        vel = torch.zeros(*rot0.shape[:-2], self.dof_size, dtype=rot0.dtype, device=rot0.device)
        if self._hinge_j.numel():
            vel[..., self._hinge_d] = (e[..., self._hinge_j, :] * self._hinge_axis.to(e)).sum(-1) / dt
        if self._sph_j.numel():
            vel[..., self._sph_d] = e[..., self._sph_j, :] / dt
        return vel

    def compute_frame_dof_vel(self, joint_rot: torch.Tensor, dt: float) -> torch.Tensor:
        """Finite-difference DoF velocities of a clip [T, J-1, 4] → [T, D]; the last row repeats."""
        vel = self.compute_dof_vel(joint_rot[:-1], joint_rot[1:], dt)
        if vel.shape[0] == 0:
            return torch.zeros(joint_rot.shape[0], self.dof_size, dtype=joint_rot.dtype)
        return torch.cat([vel, vel[-1:]], dim=0)

    # --------------------------------------------------------------- internals
    def _build_index(self) -> None:
        hinge_j, hinge_d, axes, sph_j, sph_d = [], [], [], [], []
        offset = 0
        for j, joint in enumerate(self.joints[1:]):
            if joint.dof_idx != offset:
                raise MimicKitError(f"{self.source}: joint '{joint.name}' has DoF index {joint.dof_idx}")
            if joint.type == JointType.HINGE:
                hinge_j.append(j)
                hinge_d.append(offset)
                axes.append(joint.axis)
            elif joint.type == JointType.SPHERICAL:
                sph_j.append(j)
                sph_d.append([offset, offset + 1, offset + 2])
            offset += joint.dof_dim
        self.dof_size = offset
        dev = self.device
        self._hinge_j = torch.tensor(hinge_j, dtype=torch.long, device=dev)
        self._hinge_d = torch.tensor(hinge_d, dtype=torch.long, device=dev)
        self._hinge_axis = torch.tensor(np.array(axes).reshape(-1, 3), dtype=torch.float32, device=dev)
        self._sph_j = torch.tensor(sph_j, dtype=torch.long, device=dev)
        self._sph_d = torch.tensor(sph_d, dtype=torch.long, device=dev).reshape(-1, 3)
        depth = [0] * len(self.parent_ids)
        for j in range(1, len(self.parent_ids)):
            depth[j] = depth[self.parent_ids[j]] + 1
        # Per depth level: body ids, their parents and their joints (body id - 1).
        self._fk_levels: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = []
        for level in range(1, max(depth, default=0) + 1):
            ids = torch.tensor([j for j, d in enumerate(depth) if d == level], dtype=torch.long, device=dev)
            parents = torch.tensor([self.parent_ids[j] for j in ids.tolist()], dtype=torch.long, device=dev)
            self._fk_levels.append((ids, parents, ids - 1))
        self._fk_local_rot = self.local_rot[1:]
        self._fk_parents = torch.tensor(self.parent_ids[1:], dtype=torch.long, device=dev)
        self._fk_offsets = self.local_pos[1:]
        # paths[i, a] = 1 when body a + 1 lies on the path from the root to body i (itself included).
        n = len(self.parent_ids)
        paths = torch.zeros(n, max(n - 1, 0), dtype=self.local_pos.dtype, device=dev)
        for j in range(1, n):
            a = j
            while a > 0:
                paths[j, a - 1] = 1.0
                a = self.parent_ids[a]
        self._fk_paths = paths
