"""The 3D scene in viser: a character drawn from its MJCF (mjviser), a dark ground grid, the root
path of the clip, foot-contact markers, and a camera that follows the character.

Camera follow moves the world, not the camera: the character's root is kept over the origin (in x, y)
and the ground, path and markers shift under it, so each browser keeps its own orbit/zoom.
"""

from __future__ import annotations

import re
import threading
import warnings
from pathlib import Path

import mujoco
import numpy as np
import viser
from mjviser import ViserMujocoScene

from mimickit.anim.mjcf_loader import load_mjcf_model
from studio.clip_pose import ClipPose

# Colours (RGB 0-1): the left side blue, the right side coral, the trunk sand; hands and feet darker.
_TRUNK = (0.85, 0.74, 0.52)
_LEFT = (0.33, 0.60, 0.86)
_RIGHT = (0.90, 0.46, 0.37)
_EXTREMITY_SHADE = 0.75
_LEFT_NAME = re.compile(r"(^|_)(left|l)(_|$)|^[fhr]l_", re.IGNORECASE)
_RIGHT_NAME = re.compile(r"(^|_)(right|r)(_|$)|^[fhr]r_", re.IGNORECASE)
_EXTREMITY_NAME = re.compile(r"hand|foot|toe|wrist|ankle", re.IGNORECASE)

PATH_COLOR = (250, 176, 5)
CONTACT_COLOR = (60, 220, 120)
MAX_PATH_POINTS = 400


def body_color(name: str) -> tuple[float, float, float]:
    base = _LEFT if _LEFT_NAME.search(name) else _RIGHT if _RIGHT_NAME.search(name) else _TRUNK
    shade = _EXTREMITY_SHADE if _EXTREMITY_NAME.search(name) else 1.0
    return (base[0] * shade, base[1] * shade, base[2] * shade)


def colour_model(m: mujoco.MjModel) -> None:
    """Give every visible geom its body's side colour (materials would override rgba, so drop them)."""
    for g in range(m.ngeom):
        if m.geom_rgba[g, 3] == 0:
            continue
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, int(m.geom_bodyid[g])) or ""
        m.geom_rgba[g, :3] = body_color(name)
        m.geom_matid[g] = -1


class StudioScene:
    """Owns the viser scene nodes. Thread-safe: the player thread and API handlers both draw."""

    def __init__(self, server: viser.ViserServer) -> None:
        self.server = server
        self._lock = threading.RLock()
        self._char_path: Path | None = None
        self._mj: ViserMujocoScene | None = None
        self._body_map: np.ndarray = np.zeros(0, dtype=np.int64)  # char body j -> MuJoCo body id
        self._contacts: list[viser.CylinderHandle] = []
        server.scene.set_up_direction("+z")
        server.scene.world_axes.visible = False
        self.world = server.scene.add_frame("/world", show_axes=False)
        server.scene.add_grid(
            "/world/ground",
            width=60.0,
            height=60.0,
            infinite_grid=True,
            cell_size=0.5,
            section_size=2.0,
            cell_color=(78, 84, 96),
            section_color=(112, 120, 136),
            plane_color=(44, 48, 56),
            plane_opacity=1.0,
            shadow_opacity=0.35,
            fade_distance=40.0,
        )
        server.initial_camera.position = (2.2, -2.6, 1.5)
        server.initial_camera.look_at = (0.0, 0.0, 0.8)

    # -- character and clip --------------------------------------------------------------------------

    def show_clip(self, pose: ClipPose) -> None:
        """Draw `pose`'s character (rebuilt only when it changes), its root path and foot markers."""
        with self._lock:
            if self._char_path != pose.char_path:
                self._build_character(pose)
            root = pose.root_pos
            step = max(1, len(root) // MAX_PATH_POINTS)
            points = np.concatenate([root[::step], root[-1:]]).astype(np.float64)
            points[:, 2] = 0.01  # the path is drawn on the ground
            if len(points) >= 2:
                self.server.scene.add_spline_catmull_rom(
                    "/world/root_path", points=points, color=PATH_COLOR, thickness=0.015
                )
            for h in self._contacts:
                h.remove()
            self._contacts = [
                self.server.scene.add_cylinder(
                    f"/world/contacts/{name}",
                    radius=0.09,
                    height=0.006,
                    color=CONTACT_COLOR,
                    cast_shadow=False,
                    visible=False,
                )
                for name in pose.feet
            ]

    def _build_character(self, pose: ClipPose) -> None:
        self.server.scene.remove_by_name("/bodies")  # the previous character's mjviser nodes
        self.server.scene.remove_by_name("/fixed_bodies")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = load_mjcf_model(pose.char_path)
        colour_model(model)
        self._mj = ViserMujocoScene(self.server, model, num_envs=1)
        self._mj.camera_tracking_enabled = False  # we follow by moving the world (see module doc)
        names = pose.char.get_body_names()
        self._body_map = np.array([mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, n) for n in names])
        self._char_path = pose.char_path

    def draw(self, pose: ClipPose, frame: int, follow: bool) -> np.ndarray:
        """Pose the character at `frame`; returns the world offset applied (root x, y when following)."""
        with self._lock:
            if self._mj is None:
                return np.zeros(3)
            model = self._mj.mj_model
            offset = np.zeros(3)
            if follow:
                offset[:2] = pose.root_pos[frame, :2]
            xpos = np.zeros((1, model.nbody, 3))
            xmat = np.tile(np.eye(3), (1, model.nbody, 1, 1))
            xpos[0, self._body_map] = pose.body_pos[frame] - offset
            xmat[0, self._body_map] = pose.body_xmat[frame]
            with self.server.atomic():
                self.world.position = -offset
                in_contact = pose.contacts(frame)
                for i, h in enumerate(self._contacts):
                    h.visible = bool(in_contact[i])
                    if in_contact[i]:
                        j = pose.char.get_body_id(pose.feet[i])
                        h.position = (*pose.body_pos[frame, j, :2], 0.003)
                self._mj.update_from_arrays(xpos, xmat)
            # mjviser flushes inside the atomic block, where viser's sender may not take the messages;
            # a flush after it wakes the sender when it can (without it, 60 Hz playback reached a
            # client at ~10 poses/s here, 45 Hz at the full rate).
            self.server.flush()
            return offset
