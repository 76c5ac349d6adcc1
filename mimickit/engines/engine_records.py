"""What both engines keep per object: the `create_obj` record, the base of an object's layout in the built
model, and its getter tensors. Each engine subclasses the layout with the indices of its own model (MuJoCo
qpos/sensor columns, Newton joint_q/joint_qd columns)."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from typing import TYPE_CHECKING

import numpy as np
import torch

if TYPE_CHECKING:
    from mimickit.anim.kin_char_model import KinCharModel


class ObjType(IntEnum):
    """What `create_obj` builds: a rigid body or an articulated character (the reference's numbers)."""

    rigid = 0
    articulated = 1


@dataclass(frozen=True)
class ObjRecord:
    """What `create_obj` was asked for; identical in every env except the start pose. The field names are
    `create_obj`'s keyword arguments (the Newton engine rebuilds its scene in MuJoCo from them)."""

    obj_type: ObjType
    asset_file: str
    name: str
    is_visual: bool
    enable_self_collisions: bool
    fix_root: bool
    color: tuple[float, ...] | None
    disable_motors: bool

    def signature(self) -> tuple:
        """Equal signatures = the same object (the name and colour do not change the physics)."""
        return (self.obj_type, self.asset_file, self.is_visual, self.enable_self_collisions, self.fix_root,
                self.disable_motors)  # fmt: skip


@dataclass(kw_only=True)
class ObjLayout:
    """Where an object lives in an engine's built model; each engine's subclass adds its model's indices."""

    kin: KinCharModel
    actuated: bool  # its DoFs have actuators (`engine.has_motors`)
    kp: np.ndarray = field(default_factory=lambda: np.zeros(0))  # [D] gains as used by the control mode
    kd: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def num_dofs(self) -> int:
        return self.kin.get_dof_size()

    @property
    def num_bodies(self) -> int:
        return self.kin.get_num_joints()


ROOT_VIEWS = {"root_pos": "body_pos", "root_rot": "body_rot", "root_vel": "body_vel", "root_ang_vel": "body_ang_vel"}
"""Root getters are views of body 0 of the body buffers (the root is body 0)."""


def state_shapes(n: int, b: int, d: int, joint_rot: bool) -> dict[str, tuple[int, ...]]:
    """Getter buffer shapes of an object with `b` bodies and `d` DoFs in `n` envs; joint_rot [N, B-1, 4]
    only for an engine that reads joint rotations directly."""
    shapes = {
        "body_pos": (n, b, 3), "body_rot": (n, b, 4), "body_vel": (n, b, 3), "body_ang_vel": (n, b, 3),
        "contact_forces": (n, b, 3), "ground_contact_forces": (n, b, 3),
        "dof_pos": (n, d), "dof_vel": (n, d), "dof_forces": (n, d),
    }  # fmt: skip
    if joint_rot:
        shapes["joint_rot"] = (n, max(b - 1, 0), 4)
    return shapes


class ObjState:
    """One object's getter tensors by name (`state_shapes`, plus the `ROOT_VIEWS` of body 0). Engines
    refresh them in place, so what a getter returned stays live."""

    def __init__(self, tensors: dict[str, torch.Tensor]):
        self.tensors = dict(tensors)
        for root, body in ROOT_VIEWS.items():
            self.tensors[root] = self.tensors[body][:, 0]

    @classmethod
    def zeros(cls, n: int, b: int, d: int, device: torch.device, joint_rot: bool = False) -> ObjState:
        return cls({k: torch.zeros(s, device=device) for k, s in state_shapes(n, b, d, joint_rot).items()})
