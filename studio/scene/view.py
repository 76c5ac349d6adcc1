"""The 3D scene in viser: a character drawn from its MJCF (mjviser), a dark ground grid, the root
path of the clip, foot-contact markers, and a camera that follows the character. For a live rollout
the scene shows the MuJoCo model of the engine's `mujoco_view` instead (either engine): the simulated
character, each body coloured by its current tracking error when the env has a reference (in its side
colours otherwise), and the reference character (the env's visual-only "ghost") as a translucent green
figure.

Camera follow moves the world, not the camera: the character's root is kept over the origin (in x, y)
and the ground, path and markers shift under it, so each browser keeps its own orbit/zoom. Height is
followed too, by the level the character stands on (`support_height`): a clip that climbs (or a
rollout whose reference climbs) stays in view, while a walk, a squat or a jump leaves the ground where
it is (the feet never sink through it).
"""

from __future__ import annotations

import copy
import re
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np
import viser
from mjviser import ViserMujocoScene
from mjviser.conversions import merge_geoms

from mimickit.anim.mjcf_loader import load_mjcf_model
from mimickit.util.warn import collect_warnings
from studio.scene.clip_pose import ClipPose

# Colours (RGB 0-1): the left side blue, the right side coral, the trunk sand; hands and feet darker.
_TRUNK = (0.85, 0.74, 0.52)
_LEFT = (0.33, 0.60, 0.86)
_RIGHT = (0.90, 0.46, 0.37)
_EXTREMITY_SHADE = 0.75
_LEFT_NAME = re.compile(r"(^|_)(left|l)(_|$)|^[fhr]l_", re.IGNORECASE)
_RIGHT_NAME = re.compile(r"(^|_)(right|r)(_|$)|^[fhr]r_", re.IGNORECASE)
_EXTREMITY_NAME = re.compile(r"hand|foot|toe|wrist|ankle", re.IGNORECASE)

GHOST_COLOR = (120, 230, 150)
GHOST_OPACITY = 0.38
# A rollout's character and ghost stand side by side along x (the env's ref_char_offset): a front
# view, aimed right of the pair so that viser's panel (top right) does not hide the ghost.
ROLLOUT_CAMERA = {"position": (0.5, -3.4, 1.35), "look_at": (0.75, 0.0, 0.7)}
# An A/B rollout: B's character and ghost in a second lane 3 m behind A's (+y), seen from higher up
# at the front, so that B's row stands above A's in the picture instead of hidden behind it.
PAIR_LANE = np.array([0.0, 3.0, 0.0])
PUSH_COLOR = (0, 200, 255)  # a push's arrow: cyan, apart from the error colours (green to red) and the ghost
PAIR_CAMERA = {"position": (0.0, -3.3, 3.4), "look_at": (0.0, 1.5, 0.7)}
# A rollout of several envs: the others' figures (envs 1..) translucent when overlaid on env 0's, and an
# env's figure red for a while after it fell (studio.scene.rollout.FALL_MARK_S).
CROWD_OPACITY = 0.35
FALL_COLOR = (225, 50, 45)
CLIP_CAMERA = {"position": (2.2, -2.6, 1.5), "look_at": (0.0, 0.0, 0.8)}
PATH_COLOR = (250, 176, 5)
CONTACT_COLOR = (60, 220, 120)
MAX_PATH_POINTS = 400
SUPPORT_WINDOW_S = 0.5  # the standing level is the lowest foot within this many seconds either side
# A rollout's per-body tracking error (metres) colours the character: pale steel at 0, amber at half
# the scale, red at the scale and above (no green: the ghost beside it is green). The page's bar chart
# takes the same stops from the scene state.
BODY_ERROR_SCALE_M = 0.3
BODY_ERROR_STOPS = ((195, 210, 230), (245, 185, 55), (225, 50, 45))


def support_height(low_z: np.ndarray, fps: float, window_s: float = SUPPORT_WINDOW_S) -> np.ndarray:
    """The level [T] to keep in view, from the lowest point of the feet per frame [T]: the minimum
    over a window of +-`window_s` (a lifted foot, a jump do not count), then averaged over the same
    window (a step up is a ramp, not a jump). Never above the feet: each averaged minimum is at most
    the frame's own lowest point."""
    w = max(1, round(window_s * fps))
    n = len(low_z)
    padded = np.pad(np.asarray(low_z, dtype=np.float64), w, mode="edge")
    lows = np.lib.stride_tricks.sliding_window_view(padded, 2 * w + 1).min(axis=1)
    lows = np.pad(lows, w, mode="edge")
    return np.lib.stride_tricks.sliding_window_view(lows, 2 * w + 1).mean(axis=1)[:n]


def error_colour(error_m: float, scale_m: float = BODY_ERROR_SCALE_M) -> tuple[int, int, int]:
    """The colour (RGB 0-255) of a body `error_m` metres off its reference: piecewise linear through
    BODY_ERROR_STOPS over [0, scale_m], clamped beyond."""
    t = min(max(float(error_m) / scale_m, 0.0), 1.0) * (len(BODY_ERROR_STOPS) - 1)
    i = min(int(t), len(BODY_ERROR_STOPS) - 2)
    a, b, f = BODY_ERROR_STOPS[i], BODY_ERROR_STOPS[i + 1], t - i
    # Halves round up, as the page's Math.round does (Python's round() would round them to even).
    return tuple(int(a[k] + (b[k] - a[k]) * f + 0.5) for k in range(3))  # type: ignore[return-value]


def body_color(name: str) -> tuple[float, float, float]:
    base = _LEFT if _LEFT_NAME.search(name) else _RIGHT if _RIGHT_NAME.search(name) else _TRUNK
    shade = _EXTREMITY_SHADE if _EXTREMITY_NAME.search(name) else 1.0
    return (base[0] * shade, base[1] * shade, base[2] * shade)


def colour_model(m: mujoco.MjModel) -> None:
    """Give every visible geom its body's side colour (materials would override rgba, so drop them).
    Body names may carry an engine prefix (`0_character/left_foot`): the last part decides."""
    for g in range(m.ngeom):
        if m.geom_rgba[g, 3] == 0:
            continue
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, int(m.geom_bodyid[g])) or ""
        m.geom_rgba[g, :3] = body_color(name.rsplit("/", 1)[-1])
        m.geom_matid[g] = -1


def rollout_view_model(model: mujoco.MjModel, ghost_bodies: np.ndarray) -> mujoco.MjModel:
    """A copy of an env's model for drawing: side colours, the ghost's and the floor's geoms made
    invisible to mjviser (the ghost is drawn translucent by the scene; the studio has its own ground)."""
    m = copy.deepcopy(model)
    ghost = np.isin(m.geom_bodyid, ghost_bodies)
    for g in range(m.ngeom):
        if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE:
            m.geom_type[g] = mujoco.mjtGeom.mjGEOM_BOX  # mjviser would draw a plane as a second grid
            m.geom_rgba[g, 3] = 0.0
        elif ghost[g]:
            m.geom_rgba[g, 3] = 0.0
    colour_model(m)
    return m


class StudioScene:
    """Owns the viser scene nodes. The studio's one scene thread draws (`studio.scene.thread`); the lock
    lets other threads read what is drawn (figures, body colours, the clip character)."""

    def __init__(self, server: viser.ViserServer) -> None:
        self.server = server
        self._lock = threading.RLock()
        self._char_path: Path | None = None
        self._mj: ViserMujocoScene | None = None
        self._body_map: np.ndarray = np.zeros(0, dtype=np.int64)  # char body j -> MuJoCo body id
        self._nbody = 0  # bodies of the clip character's MuJoCo model (world included)
        self._contacts: list[viser.CylinderHandle] = []
        self._support: tuple[ClipPose | None, np.ndarray] = (None, np.zeros(0))
        self.mode = "clip"  # "clip": the player draws; "rollout": a rollout draws (clip draws are ignored)
        self._ghost: list[tuple[int, viser.MeshHandle]] = []  # (MuJoCo body id, its translucent mesh)
        self._error_meshes: list[tuple[int, viser.MeshHandle]] = []  # the character's bodies, by error
        self._error_colours: list[tuple[int, int, int] | None] = []  # the colour each was last sent
        self._partner: _Partner | None = None  # B of an A/B rollout
        self._crowd: _Crowd | None = None  # envs 1.. of a rollout of several
        self._push_shown = False  # whether push arrows are drawn (see draw_push)
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
        self._set_camera(CLIP_CAMERA, clients=False)

    # -- character and clip --------------------------------------------------------------------------

    def show_clip(self, pose: ClipPose) -> None:
        """Draw `pose`'s character (rebuilt only when it changes), its root path and foot markers."""
        with self._lock:
            if self.mode != "clip":
                self._clear_rollout()
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

    def watched(self) -> bool:
        """Whether a browser shows the 3D view (a viser client is connected)."""
        return bool(self.server.get_clients())

    def drawn_character(self) -> Path | None:
        """The character file of the clip the view draws (None: no clip character, e.g. a rollout's)."""
        with self._lock:
            return self._char_path if self.mode == "clip" and self._mj is not None else None

    def _build_character(self, pose: ClipPose) -> None:
        self.server.scene.remove_by_name("/bodies")  # the previous character's mjviser nodes
        self.server.scene.remove_by_name("/fixed_bodies")
        with collect_warnings():  # dropped, as before (meshes the MJCF lacks)
            model = load_mjcf_model(pose.char_path)
        colour_model(model)
        self._mj = ViserMujocoScene(self.server, model, num_envs=1)
        self._mj.camera_tracking_enabled = False  # we follow by moving the world (see module doc)
        names = pose.char.get_body_names()
        self._body_map = np.array([mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, n) for n in names])
        self._nbody = model.nbody
        self._char_path = pose.char_path

    def draw(self, pose: ClipPose, frame: int, follow: bool) -> np.ndarray:
        """Pose the character at `frame`; returns the world offset applied (root x, y when following)."""
        with self._lock:
            if self._mj is None or self.mode != "clip" or self._char_path != pose.char_path:
                return np.zeros(3)
            offset = np.zeros(3)
            if follow:
                offset[:2] = pose.root_pos[frame, :2]
                offset[2] = self._clip_support(pose)[frame]
            xpos = np.zeros((1, self._nbody, 3))
            xmat = np.tile(np.eye(3), (1, self._nbody, 1, 1))
            xpos[0, self._body_map] = pose.body_pos[frame] - offset
            xmat[0, self._body_map] = pose.body_xmat[frame]
            with self.server.atomic():
                self.world.position = -offset
                in_contact = pose.contacts(frame)
                for i, h in enumerate(self._contacts):
                    h.visible = bool(in_contact[i])
                    if in_contact[i]:
                        j = pose.char.get_body_id(pose.feet[i])
                        h.position = (*pose.body_pos[frame, j, :2], 0.003 + offset[2])
                self._mj.update_from_arrays(xpos, xmat)
            # mjviser flushes inside the atomic block, where viser's sender may not take the messages;
            # a flush after it wakes the sender when it can (without it, 60 Hz playback reached a
            # client at ~10 poses/s here, 45 Hz at the full rate).
            self.server.flush()
            return offset

    def _clip_support(self, pose: ClipPose) -> np.ndarray:
        """`support_height` of the clip's feet (of its root when it has no feet), once per clip."""
        if self._support[0] is not pose:
            low = pose.foot_low_z.min(axis=1) if pose.foot_low_z.shape[1] else pose.root_pos[:, 2] - pose.root_pos[0, 2]
            self._support = (pose, support_height(low, pose.fps))
        return self._support[1]

    # -- rollout: an env's own model, character and ghost ------------------------------------------

    def show_rollout(
        self,
        model: mujoco.MjModel,
        ghost_bodies: np.ndarray,
        error_bodies: np.ndarray | None = None,
        *,
        partner: tuple[mujoco.MjModel, np.ndarray, np.ndarray] | None = None,
    ) -> None:
        """Replace whatever is drawn by the env model `model`; bodies `ghost_bodies` are the reference.
        `error_bodies`, the character's bodies, are drawn one mesh each for `colour_bodies` to colour by
        their tracking error (mjviser's batched meshes have one colour baked in per shared geometry).
        `partner`: B of an A/B rollout, (model, ghost bodies, character bodies), drawn in a lane behind,
        each figure labelled."""
        error_bodies = np.zeros(0, dtype=np.int64) if error_bodies is None else np.asarray(error_bodies)
        with self._lock:
            self._clear_clip()
            self._clear_rollout()
            self.mode = "rollout"
            view = rollout_view_model(model, np.concatenate([ghost_bodies, error_bodies]))
            self._mj = ViserMujocoScene(self.server, view, num_envs=1)
            self._mj.camera_tracking_enabled = False  # we follow by moving the world (see module doc)
            self._ghost = self._body_meshes(model, ghost_bodies, "/ghost", GHOST_COLOR, GHOST_OPACITY)
            self._error_meshes = self._body_meshes(model, error_bodies, "/error_bodies", None, 1.0, shadows=True)
            self._error_colours = [None] * len(self._error_meshes)
            if partner is not None:
                self._partner = self._partner_figure(*partner)
                self._set_camera(PAIR_CAMERA, clients=True)
            elif self._ghost:
                self._set_camera(ROLLOUT_CAMERA, clients=True)

    def _partner_figure(self, model: mujoco.MjModel, ghost_bodies: np.ndarray, char_bodies: np.ndarray) -> _Partner:
        """B's ghost and character, one mesh per body (B has no mjviser scene of its own), and a label
        over each figure: "A" and "B"."""
        ghost = self._body_meshes(model, ghost_bodies, "/b/ghost", GHOST_COLOR, GHOST_OPACITY)
        bodies = self._body_meshes(model, np.asarray(char_bodies), "/b/bodies", None, 1.0, shadows=True)
        labels = [self.server.scene.add_label(f"/b/label_{k}", k, font_screen_scale=1.4) for k in "AB"]
        return _Partner(ghost, bodies, labels, [None] * len(bodies))

    def _body_meshes(
        self,
        model: mujoco.MjModel,
        bodies: np.ndarray,
        prefix: str,
        color: tuple[int, int, int] | None,
        opacity: float,
        shadows: bool = False,
    ) -> list[tuple[int, viser.MeshHandle]]:
        """One mesh per body of `bodies` with visible geoms, in its body frame; `color` None: the body's
        side colour (until `colour_bodies` sets another)."""
        out = []
        for b in bodies:
            geometry = _body_geometry(model, int(b))
            if geometry is None:
                continue
            vertices, faces, side_rgb = geometry
            handle = self.server.scene.add_mesh_simple(
                f"{prefix}/b{int(b)}",
                vertices,
                faces,
                color=color or side_rgb,
                opacity=opacity,
                cast_shadow=shadows,
                receive_shadow=False,
            )
            out.append((int(b), handle))
        return out

    def show_crowd(
        self, model: mujoco.MjModel, char_bodies: np.ndarray, cells: np.ndarray, overlay: bool, label_z: float = 2.0
    ) -> None:
        """Envs 1.. of a rollout of several (after `show_rollout`, which draws env 0): one batched mesh per
        character body with an instance per env, so a frame sends two messages per body for all envs
        (one mesh per body and env would be N x bodies). Under /world: positions are world coordinates
        and follow moves them with the ground. `cells` [N, 3]: each env's place (env 0's first); a grid
        (`overlay` False) labels each cell `label_z` m up, an overlay draws the others translucent."""
        with self._lock:
            k = len(cells) - 1
            meshes = []
            for b in np.asarray(char_bodies):
                geometry = _body_geometry(model, int(b))
                if geometry is None or k < 1:
                    continue
                vertices, faces, rgb = geometry
                handle = self.server.scene.add_batched_meshes_simple(
                    f"/world/crowd/b{int(b)}",
                    vertices,
                    faces,
                    batched_wxyzs=np.tile(np.array([1.0, 0.0, 0.0, 0.0], dtype=np.float32), (k, 1)),
                    batched_positions=np.zeros((k, 3), dtype=np.float32),
                    batched_colors=np.tile(np.array(rgb, dtype=np.uint8), (k, 1)),
                    batched_opacities=np.full(k, CROWD_OPACITY, dtype=np.float32) if overlay else None,
                    lod="off",  # a body is a few hundred triangles; viser's automatic LOD would re-mesh it
                    cast_shadow=not overlay,
                    receive_shadow=False,
                )
                meshes.append((int(b), handle, np.array(rgb, dtype=np.uint8)))
            labels = [] if overlay else [
                self.server.scene.add_label(f"/world/crowd/label_{i}", f"{i}", position=(c[0], c[1], label_z),
                                            font_screen_scale=0.8)
                for i, c in enumerate(np.asarray(cells))
            ]  # fmt: skip
            self._crowd = _Crowd(meshes, labels, np.zeros(k, dtype=bool), [-1] * len(labels))
            if not overlay:
                self._set_camera(_grid_camera(np.asarray(cells)), clients=True)

    def draw_crowd(self, xpos: np.ndarray, xmat: np.ndarray, marked: np.ndarray, falls: list[int]) -> None:
        """Pose envs 1..'s figures: xpos [K, nbody, 3] (world, their cells added), xmat [K, nbody, 9];
        `marked` [K]: drawn red (a recent fall); `falls` [N]: each env's falls, on the grid's labels."""
        with self._lock:
            c = self._crowd
            if c is None or self.mode != "rollout":
                return
            quat = np.zeros(4)
            recolour = not np.array_equal(marked, c.marked)
            with self.server.atomic():
                for b, h, rgb in c.meshes:
                    wxyz = np.empty((len(xmat), 4), dtype=np.float32)
                    for j in range(len(xmat)):
                        mujoco.mju_mat2Quat(quat, xmat[j, b])
                        wxyz[j] = quat
                    h.batched_positions = xpos[:, b].astype(np.float32)
                    h.batched_wxyzs = wxyz
                    if recolour:
                        h.batched_colors = np.where(marked[:, None], np.array(FALL_COLOR, dtype=np.uint8), rgb)
                for i, label in enumerate(c.labels):
                    if falls[i] != c.falls[i]:  # sent only when it changes
                        label.text = f"{i}: {falls[i]} fall{'s' if falls[i] != 1 else ''}"
                        c.falls[i] = falls[i]
            c.marked = np.asarray(marked, dtype=bool).copy()

    def crowd(self) -> dict[str, object] | None:
        """What is drawn of envs 1.. (None: one env): the body meshes, and per env its root's place and
        whether it is marked red, read from the mesh handles (the first is the root's)."""
        with self._lock:
            c = self._crowd
            if c is None or not c.meshes:
                return None
            root = c.meshes[0][1]
            red = np.all(np.asarray(root.batched_colors) == np.array(FALL_COLOR), axis=1)
            return {
                "bodies": len(c.meshes),
                "at": [[round(float(v), 3) for v in p] for p in np.asarray(root.batched_positions)],
                "red": [bool(x) for x in red],
                "labels": [label.text for label in c.labels],
            }

    def on_body_click(self, clicked: Callable[[int], None], dragged: Callable[[int, np.ndarray | None], None]) -> None:
        """Call `clicked(MuJoCo body id)` (on viser's thread pool) when one of the rollout character's
        bodies is clicked in the 3D view, and `dragged(body id, pull)` while one is dragged: `pull` [3] is
        the world vector from the grabbed point to the pointer on viser's camera-aligned drag plane (about
        20 updates a second), None at release. Only the bodies drawn one mesh each (`show_rollout`'s
        `error_bodies`; an env without them has nothing to click)."""

        def drag(event: viser.SceneNodeDragEvent, b: int) -> None:
            pull = np.subtract(event.end_position, event.start_position) if event.phase != "end" else None
            dragged(b, pull)

        with self._lock:
            for b, h in self._error_meshes:
                h.on_click(lambda _event, b=b: clicked(b))
                h.on_drag(lambda event, b=b: drag(event, b))

    def draw_push(self, arrows: np.ndarray) -> None:
        """Draw the pushes acting now: `arrows` [P, 2, 3] (tail, head) in the rollout model's world; none
        removes them."""
        with self._lock:
            if self.mode != "rollout" or (not len(arrows) and not self._push_shown):
                return
            if len(arrows):
                self.server.scene.add_arrows(
                    "/world/push", arrows.astype(np.float32), PUSH_COLOR, shaft_radius=0.035, head_radius=0.08,
                    head_length=0.15,
                )  # fmt: skip
            else:
                self.server.scene.remove_by_name("/world/push")
            self._push_shown = bool(len(arrows))
            self.server.flush()  # as draw_bodies: sent now, not with the next frame (paused: none comes)

    def colour_bodies(
        self, errors: dict[int, float], scale_m: float = BODY_ERROR_SCALE_M, partner: dict[int, float] | None = None
    ) -> None:
        """Colour the character's bodies (those `show_rollout` got as `error_bodies`) by their error:
        {MuJoCo body id: metres}, B's by `partner` in its model's ids; a colour is sent only when it changes."""
        with self._lock:
            if self.mode != "rollout":
                return
            with self.server.atomic():
                _colour(self._error_meshes, self._error_colours, errors, scale_m)
                if self._partner is not None and partner:
                    _colour(self._partner.bodies, self._partner.colours, partner, scale_m)

    def body_colours(self, partner: bool = False) -> dict[int, tuple[int, int, int]]:
        """The colour each of the character's error-coloured bodies shows: {MuJoCo body id: RGB 0-255}
        (`partner`: B's, in its model's ids)."""
        with self._lock:
            meshes = (self._partner.bodies if self._partner else []) if partner else self._error_meshes
            return {b: tuple(int(c) for c in h.color) for b, h in meshes}  # type: ignore[misc]

    def figures(self) -> list[dict[str, object]]:
        """The figures of an A/B rollout as the scene draws them (empty otherwise), for the state: each
        one's label, where the label stands (viser's world, over the figure) and its meshes."""
        with self._lock:
            p = self._partner
            if p is None:
                return []
            meshes = ((self._error_meshes, self._ghost), (p.bodies, p.ghost))
            return [
                {"label": k, "at": [round(float(v), 3) for v in h.position], "bodies": len(c), "ghost": len(g)}
                for k, h, (c, g) in zip("AB", p.labels, meshes, strict=True)
            ]

    def _set_camera(self, view: dict[str, tuple[float, float, float]], clients: bool) -> None:
        """The camera new browsers start with; `clients`: also move the cameras of connected ones."""
        self.server.initial_camera.position = view["position"]
        self.server.initial_camera.look_at = view["look_at"]
        if clients:
            for client in self.server.get_clients().values():
                with client.atomic():
                    client.camera.position = view["position"]
                    client.camera.look_at = view["look_at"]

    def draw_bodies(
        self,
        xpos: np.ndarray,
        xmat: np.ndarray,
        root: np.ndarray,
        follow: bool,
        height: float = 0.0,
        partner: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> np.ndarray:
        """Pose every body of the rollout model from MuJoCo's xpos [nbody, 3] / xmat [nbody, 9];
        `root` [3] is kept over the origin when following, and the ground `height` lowered to 0.
        `partner`: B's xpos / xmat in its own model, drawn in its lane (PAIR_LANE)."""
        with self._lock:
            if self._mj is None or self.mode != "rollout":
                return np.zeros(3)
            offset = np.zeros(3)
            if follow:
                offset[:2] = root[:2]
                offset[2] = height
            pos = xpos - offset
            mats = xmat.reshape(-1, 3, 3)
            with self.server.atomic():
                self.world.position = -offset
                _place(self._ghost + self._error_meshes, pos, mats)
                if self._partner is not None and partner is not None:
                    b_pos = partner[0] + PAIR_LANE - offset
                    _place(self._partner.ghost + self._partner.bodies, b_pos, partner[1].reshape(-1, 3, 3))
                    for label, p in zip(self._partner.labels, (pos, b_pos), strict=True):
                        label.position = _label_at(p)
                self._mj.update_from_arrays(pos[None], mats[None])
            self.server.flush()  # see draw()
            return offset

    def _clear_clip(self) -> None:
        self.server.scene.remove_by_name("/world/root_path")
        for h in self._contacts:
            h.remove()
        self._contacts = []
        self.server.scene.remove_by_name("/bodies")
        self.server.scene.remove_by_name("/fixed_bodies")
        self._mj = None
        self._char_path = None

    def _clear_rollout(self) -> None:
        for _, h in self._ghost + self._error_meshes:
            h.remove()
        self._ghost, self._error_meshes, self._error_colours = [], [], []
        self._partner = None
        self._crowd = None
        self.server.scene.remove_by_name("/world/crowd")
        self.server.scene.remove_by_name("/ghost")
        self.server.scene.remove_by_name("/error_bodies")
        self.server.scene.remove_by_name("/b")
        self.server.scene.remove_by_name("/world/push")
        self._push_shown = False
        self.server.scene.remove_by_name("/bodies")
        self.server.scene.remove_by_name("/fixed_bodies")
        self._mj = None
        self._char_path = None
        self.mode = "clip"

    def end_rollout(self) -> None:
        """Remove the rollout's model; the next clip builds its character again."""
        with self._lock:
            if self.mode == "rollout":
                self._clear_rollout()
                self._set_camera(CLIP_CAMERA, clients=False)


@dataclass
class _Partner:
    """B's figure in an A/B rollout: its ghost and character, one mesh per body, and the two labels."""

    ghost: list[tuple[int, viser.MeshHandle]]
    bodies: list[tuple[int, viser.MeshHandle]]
    labels: list[viser.LabelHandle]
    colours: list[tuple[int, int, int] | None] = field(default_factory=list)


@dataclass
class _Crowd:
    """Envs 1.. of a rollout of several: (body id, batched mesh, side colour) per character body, a label
    per grid cell, and what was sent last (fall marks, label counts)."""

    meshes: list[tuple[int, viser.BatchedMeshHandle, np.ndarray]]
    labels: list[viser.LabelHandle]
    marked: np.ndarray
    falls: list[int]


def _body_geometry(model: mujoco.MjModel, body: int) -> tuple[np.ndarray, np.ndarray, tuple[int, int, int]] | None:
    """Body `body`'s visible geoms merged in its frame: vertices, faces and its side colour (None: no visible geom)."""
    geoms = [g for g in np.flatnonzero(model.geom_bodyid == body) if model.geom_rgba[g, 3] > 0]
    if not geoms:
        return None
    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, body) or ""
    rgb = tuple(round(c * 255) for c in body_color(name.rsplit("/", 1)[-1]))
    mesh = merge_geoms(model, geoms)
    vertices = np.asarray(mesh.vertices, dtype=np.float32)
    return vertices, np.asarray(mesh.faces, dtype=np.uint32), rgb  # type: ignore[return-value]


def _grid_camera(cells: np.ndarray) -> dict[str, tuple[float, float, float]]:
    """A camera that sees a grid of envs' cells [N, 3] (and env 0's ghost beside its cell) from the front, higher
    and further back the larger the grid."""
    lo, hi = cells[:, :2].min(axis=0), cells[:, :2].max(axis=0)
    cx, cy = (lo[0] + hi[0] + 2.0) / 2, (lo[1] + hi[1]) / 2
    extent = float(max(hi - lo)) + 2.0
    return {"position": (cx, lo[1] - 0.8 * extent - 1.2, 0.6 * extent + 1.2), "look_at": (cx, cy, 0.5)}


def _label_at(pos: np.ndarray) -> np.ndarray:
    """Where a figure's label goes: over the middle of its bodies (`pos` [nbody, 3] of its model), 25 cm
    above the highest."""
    bodies = pos[1:]  # body 0 is MuJoCo's world
    return np.array([bodies[:, 0].mean(), bodies[:, 1].mean(), bodies[:, 2].max() + 0.25])


def _place(meshes: list[tuple[int, viser.MeshHandle]], pos: np.ndarray, mats: np.ndarray) -> None:
    """Move each (MuJoCo body id, mesh) to its body's pose: pos [nbody, 3], mats [nbody, 3, 3]."""
    wxyz = np.zeros(4)
    for b, h in meshes:
        mujoco.mju_mat2Quat(wxyz, mats[b].reshape(9))
        h.position = pos[b]
        h.wxyz = wxyz.copy()


def _colour(
    meshes: list[tuple[int, viser.MeshHandle]],
    sent: list[tuple[int, int, int] | None],
    errors: dict[int, float],
    scale_m: float,
) -> None:
    """Set each mesh whose body is in `errors` to its error colour, when it differs from the one `sent`."""
    for i, (b, h) in enumerate(meshes):
        if b not in errors:
            continue
        rgb = error_colour(errors[b], scale_m)
        if rgb != sent[i]:
            h.color = rgb
            sent[i] = rgb
