"""Points on a character's collision shapes, for ground checks of clips (lowest foot point)."""

from __future__ import annotations

import itertools

import mujoco
import numpy as np
import torch

from mimickit.anim.kin_char_model import KinCharModel
from mimickit.anim.mjcf_loader import load_mjcf_model
from mimickit.util import torch_util as tu


def body_surface_points(char: KinCharModel, body_names: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
    """Sample points on the geoms of `body_names`: (body index [P], local point [P, 3]).

    Boxes give their 8 corners; spheres and capsules the lowest points of their end spheres along
    ±x, ±y, ±z in the body frame (enough to find the lowest point of a posed body to ~mm).
    """
    m = load_mjcf_model(char.source)
    ids, pts = [], []
    for name in body_names:
        b = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)
        for g in np.where(m.geom_bodyid == b)[0]:
            rot = tu.quat_from_wxyz(torch.tensor(m.geom_quat[g], dtype=torch.float32))
            for p in _geom_points(m, g):
                pts.append(m.geom_pos[g] + tu.quat_rotate(rot, torch.tensor(p, dtype=torch.float32)).numpy())
                ids.append(char.get_body_id(name))
    return torch.tensor(ids), torch.tensor(np.array(pts), dtype=torch.float32)


def _geom_points(m: mujoco.MjModel, g: int) -> list[np.ndarray]:
    size = m.geom_size[g]
    t = m.geom_type[g]
    if t == mujoco.mjtGeom.mjGEOM_BOX:
        return [np.array(s) * size for s in itertools.product((-1, 1), repeat=3)]
    r = size[0]
    centres = [np.zeros(3)]
    if t == mujoco.mjtGeom.mjGEOM_CAPSULE:
        centres = [np.array([0, 0, -size[1]]), np.array([0, 0, size[1]])]
    dirs = [np.array(d) * r for d in np.vstack([np.eye(3), -np.eye(3)])]
    return [c + d for c in centres for d in dirs]


def lowest_point_z(
    char: KinCharModel, body_ids: torch.Tensor, local_pts: torch.Tensor, body_pos: torch.Tensor, body_rot: torch.Tensor
) -> torch.Tensor:
    """Lowest world z [T] of the points, given posed bodies body_pos [T, J, 3], body_rot [T, J, 4]."""
    pos = body_pos[:, body_ids]
    rot = body_rot[:, body_ids]
    world = pos + tu.quat_rotate(rot, local_pts.expand(pos.shape[0], -1, -1))
    return world[..., 2].min(dim=-1).values
