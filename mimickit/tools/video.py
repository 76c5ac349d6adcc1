"""MP4 videos of clips and policies: `mimickit video` (offscreen MuJoCo rendering, one frame per control step).

Both sources run through the project's own envs, so a video shows exactly what the engine simulates:
* a clip: `ViewMotionEnv` sets the clip's pose on the character every step (kinematic playback);
* a policy: the env and agent of an arg file (as `mimickit test` builds them, one env), deterministic
  actions; the env is built with `visualize=True`, so the DeepMimic env adds its reference character,
  which is drawn translucent as a ghost. An episode that ends is reset at once, as in testing.

Either engine: frames are rendered from the engine's `mujoco_view` (its MuJoCo model of the scene and
env 0's MjData), with the character and the ghost found by the env's object ids. The camera follows the
character's root in the ground plane at a fixed height (as the reference's `track` camera), centred
between character and ghost when there is one; its distance and height scale with the character's root height
in the first frame, so that a small robot fills the frame as the humanoid does. Bodies that have no geom to
draw (an MJCF whose meshes are missing, such as MimicKit's PI+) are drawn as capsule bones to their parent.
Rendering needs an offscreen OpenGL: EGL, else OSMesa (`select_gl_backend`).
"""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import torch

from mimickit.engines.engine import EngineConfig
from mimickit.envs.char_env import CHAR_COLOR, CharEnv
from mimickit.envs.env_config import ViewMotionEnvConfig
from mimickit.envs.view_motion_env import ViewMotionEnv
from mimickit.learning.base_agent import AgentMode, BaseAgent
from mimickit.runner.inputs import resolve_inputs
from mimickit.runner.policy import load_policy
from mimickit.runner.seeding import seed_everything
from mimickit.util.arg_parser import ArgParser
from mimickit.util.config import load_config, parse_config
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA, PROJECT_DATA_DIR, DataPaths, check_output_file

GL_BACKENDS = ("egl", "osmesa")
GHOST_ALPHA = 0.4
CAMERA_DISTANCE = 3.0  # m: a standing humanoid fills about half the frame height
CAMERA_DISTANCE_GHOST = 4.5  # m: character and ghost (GHOST_OFFSET apart) fit a 4:3 frame
GHOST_OFFSET = 2.0  # m: the humanoid configs' ref_char_offset
CAMERA_ELEVATION = -18.0  # degrees
CAMERA_AZIMUTH = 90.0  # degrees: looking along +y, the side view of MimicKit's camera (it starts at y − 5)
LOOKAT_HEIGHT = 0.9  # m
HUMANOID_ROOT_HEIGHT = 0.9  # m: the camera's figures are for a character whose root starts this high
CAMERA_SCALE_RANGE = (0.3, 2.0)
BONE_RADIUS = 0.025  # of the humanoid-sized character, scaled as the camera
BONE_RGBA = np.array([0.6, 0.6, 0.6, 1.0], dtype=np.float32)  # a character with no geom to take a colour from
GRID_HALF_SIZE, GRID_STEP = 8, 1.0  # floor lines around the camera target, so that motion is visible
GRID_RGBA = np.array([0.55, 0.58, 0.62, 1.0], dtype=np.float32)
HEADLIGHT_AMBIENT, HEADLIGHT_DIFFUSE = 0.35, 0.6

_PROBE = (
    "import mujoco\n"
    "m = mujoco.MjModel.from_xml_string('<mujoco><worldbody><geom size=\"0.1\"/></worldbody></mujoco>')\n"
    "mujoco.Renderer(m, 16, 16).render()\n"
)


@dataclass
class VideoOptions:
    seconds: float = 5.0
    width: int = 640  # as the studio's Export MP4
    height: int = 480
    frame_png: Path | None = None
    """Also save the last frame as a PNG."""
    data_paths: DataPaths = PROJECT_DATA
    """Where `data/...` names (the clip, the character, the arg file's configs) are found."""

    def num_frames(self, fps: float) -> int:
        return max(1, round(self.seconds * fps))


@dataclass
class VideoInfo:
    path: Path
    frames: int
    fps: float
    width: int
    height: int
    gl_backend: str


# ------------------------------------------------------------------------------------------- GL backend
def select_gl_backend() -> str:
    """Make MuJoCo render offscreen with $MUJOCO_GL when set, else EGL, else OSMesa; returns the name.

    Each candidate is tried in a child process: a failing GL library can abort the process that loads
    it, and the backend of this process can still be switched afterwards (`_use_backend`)."""
    wanted = os.environ.get("MUJOCO_GL", "").strip().lower()
    tried = []
    for name in [wanted] if wanted else GL_BACKENDS:
        error = _probe_backend(name)
        if error is None:
            _use_backend(name)
            return name
        tried.append(f"MUJOCO_GL={name}: {error}")
    raise MimicKitError(
        f"no offscreen OpenGL for rendering ({'; '.join(tried)}); install libEGL (apt: libegl1) or OSMesa"
        " (apt: libosmesa6), or set MUJOCO_GL to a backend that works here"
    )


def _probe_backend(name: str) -> str | None:
    """None when MuJoCo can render with backend `name`, else the last line of its error."""
    env = dict(os.environ, MUJOCO_GL=name)
    try:
        proc = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, timeout=120)
    except subprocess.TimeoutExpired:
        return "timed out"
    if proc.returncode == 0:
        return None
    lines = [ln.strip() for ln in proc.stderr.splitlines() if ln.strip()]
    return lines[-1] if lines else f"exit code {proc.returncode}"


def _use_backend(name: str) -> None:
    os.environ["MUJOCO_GL"] = name
    # `import mujoco` picks its GL context class from MUJOCO_GL once (glfw when unset, which needs a
    # display); the Renderer looks the class up at construction, so reloading that module switches it.
    for module in ("mujoco.rendering.classic.gl_context", "mujoco.gl_context"):
        mod = sys.modules.get(module)
        cls = getattr(mod, "GLContext", None)
        if mod is not None and getattr(cls, "__module__", "") != f"mujoco.{name}":
            importlib.reload(mod)


# ------------------------------------------------------------------------------------------ rendering
class TrackingRenderer:
    """Renders an MjData [H, W, 3] uint8 with a camera that follows `root_body` (and the ghost's root)."""

    def __init__(
        self,
        model: mujoco.MjModel,
        width: int,
        height: int,
        root_body: int,
        ghost_root: int | None,
        bones: list[Bone] | None = None,
    ) -> None:
        model.vis.global_.offwidth = max(int(model.vis.global_.offwidth), width)
        model.vis.global_.offheight = max(int(model.vis.global_.offheight), height)
        model.vis.headlight.ambient[:] = HEADLIGHT_AMBIENT  # the scene has no lights of its own
        model.vis.headlight.diffuse[:] = HEADLIGHT_DIFFUSE
        try:
            self._renderer = mujoco.Renderer(model, height, width)
        except Exception as e:  # noqa: BLE001 - any GL failure is one user-facing error
            raise MimicKitError(f"cannot start offscreen rendering ({e.__class__.__name__}: {e})") from None
        self._root, self._ghost, self._bones = root_body, ghost_root, bones or []
        self._scale: float | None = None  # set from the first frame's root height
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        self._camera.elevation = CAMERA_ELEVATION
        self._camera.azimuth = CAMERA_AZIMUTH

    def render(self, data: mujoco.MjData) -> np.ndarray:
        if self._scale is None:
            self._scale = float(np.clip(data.xpos[self._root, 2] / HUMANOID_ROOT_HEIGHT, *CAMERA_SCALE_RANGE))
            self._camera.distance = CAMERA_DISTANCE * self._scale
            if self._ghost is not None:  # back off as the humanoid's camera does for a ghost 2 m away
                apart = float(np.linalg.norm(data.xpos[self._ghost, :2] - data.xpos[self._root, :2]))
                self._camera.distance += (CAMERA_DISTANCE_GHOST - CAMERA_DISTANCE) * apart / GHOST_OFFSET
        roots = [self._root] if self._ghost is None else [self._root, self._ghost]
        centre = data.xpos[roots, :2].mean(axis=0)
        self._camera.lookat[:] = (centre[0], centre[1], LOOKAT_HEIGHT * self._scale)
        self._renderer.update_scene(data, self._camera)
        _add_bones(self._renderer.scene, data, self._bones, BONE_RADIUS * self._scale)
        _add_floor_grid(self._renderer.scene, centre)
        return self._renderer.render()

    def close(self) -> None:
        self._renderer.close()


@dataclass(frozen=True)
class Bone:
    """A capsule drawn from body `parent` to body `child` (world positions of the frame), coloured `rgba`."""

    parent: int
    child: int
    rgba: np.ndarray


def stand_in_bones(model: mujoco.MjModel, bodies: np.ndarray) -> list[Bone]:
    """Bones for the parent-child links of `bodies` (one character) where either end has no visible geom;
    coloured as the character's visible geoms, else grey. Empty for a character whose bodies all show."""
    visible = model.geom_rgba[:, 3] > 0
    shown = np.zeros(model.nbody, dtype=bool)
    shown[model.geom_bodyid[visible]] = True
    own = np.flatnonzero(np.isin(model.geom_bodyid, bodies) & visible)
    rgba = model.geom_rgba[own[0]].copy() if len(own) else BONE_RGBA
    members = set(int(b) for b in bodies)
    bones = []
    for b in bodies:
        parent = int(model.body_parentid[b])
        if parent in members and not (shown[b] and shown[parent]):
            bones.append(Bone(parent, int(b), rgba))
    return bones


def _add_bones(scene: mujoco.MjvScene, data: mujoco.MjData, bones: list[Bone], radius: float) -> None:
    for bone in bones:
        a, b = data.xpos[bone.parent], data.xpos[bone.child]
        if scene.ngeom >= scene.maxgeom:
            return
        if np.linalg.norm(b - a) < 1e-4:  # a body fixed at its parent's origin (the PI+'s head)
            continue
        g = scene.geoms[scene.ngeom]
        mujoco.mjv_initGeom(g, mujoco.mjtGeom.mjGEOM_CAPSULE, np.zeros(3), np.zeros(3), np.eye(3).ravel(), bone.rgba)
        mujoco.mjv_connector(g, mujoco.mjtGeom.mjGEOM_CAPSULE, radius, a, b)
        scene.ngeom += 1


def _add_floor_grid(scene: mujoco.MjvScene, centre: np.ndarray) -> None:
    """Lines every GRID_STEP metres on the floor around `centre` (the floor itself is one flat colour)."""
    cx, cy = np.round(centre / GRID_STEP) * GRID_STEP
    span = GRID_HALF_SIZE * GRID_STEP
    for k in range(-GRID_HALF_SIZE, GRID_HALF_SIZE + 1):
        o = k * GRID_STEP
        for a, b in (((cx + o, cy - span), (cx + o, cy + span)), ((cx - span, cy + o), (cx + span, cy + o))):
            if scene.ngeom >= scene.maxgeom:
                return
            g = scene.geoms[scene.ngeom]
            mujoco.mjv_initGeom(g, mujoco.mjtGeom.mjGEOM_LINE, np.zeros(3), np.zeros(3), np.eye(3).ravel(), GRID_RGBA)
            mujoco.mjv_connector(g, mujoco.mjtGeom.mjGEOM_LINE, 1.0, np.array([*a, 0.002]), np.array([*b, 0.002]))
            scene.ngeom += 1


def make_ghost(model: mujoco.MjModel, bodies: np.ndarray, alpha: float = GHOST_ALPHA) -> None:
    """Draw the geoms of `bodies` translucent (rendering only: the ghost has no collisions anyway)."""
    geoms = np.flatnonzero(np.isin(model.geom_bodyid, bodies))
    model.geom_rgba[geoms, 3] = np.minimum(model.geom_rgba[geoms, 3], alpha)


# ------------------------------------------------------------------------------------------------ MP4
def write_mp4(path: str | Path, frames: Iterable[np.ndarray], fps: float, width: int, height: int) -> int:
    """Encode frames [H, W, 3] uint8 as H.264 MP4 (yuv420p, which every player reads); returns the count.
    Written to a temporary file first, so an interrupted render leaves no half video under `path`."""
    import imageio_ffmpeg

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.partial{path.suffix}")
    writer = imageio_ffmpeg.write_frames(
        str(tmp), (width, height), fps=fps, codec="libx264", pix_fmt_out="yuv420p", quality=7,
        macro_block_size=2, ffmpeg_log_level="error",
    )  # fmt: skip
    count = 0
    try:
        writer.send(None)
        for frame in frames:
            writer.send(np.ascontiguousarray(frame))
            count += 1
        writer.close()
        os.replace(tmp, path)
    except OSError as e:  # ffmpeg could not open or write the file: one line, not its whole output
        lines = str(e).strip().splitlines()
        why = e.strerror or (lines[0] if lines else type(e).__name__)
        raise MimicKitError(f"{str(path)[:200]}: cannot write the video ({why[:200]})") from None
    finally:
        writer.close()
        tmp.unlink(missing_ok=True)
    return count


def _check_output(out: Path, opts: VideoOptions) -> None:
    if out.suffix.lower() != ".mp4":
        raise MimicKitError(f"--out must be an .mp4 file, got {str(out)[:200]}")
    check_output_file(out)
    if opts.seconds <= 0:
        raise MimicKitError(f"--seconds must be positive, got {opts.seconds:g}")
    if opts.width < 16 or opts.height < 16 or opts.width % 2 or opts.height % 2:
        raise MimicKitError(f"--width and --height must be even and at least 16, got {opts.width}x{opts.height}")


def _record(out: Path, frames: Iterator[np.ndarray], fps: float, opts: VideoOptions, backend: str) -> VideoInfo:
    last: list[np.ndarray] = []

    def keep_last() -> Iterator[np.ndarray]:
        for f in frames:
            last[:] = [f]
            yield f

    count = write_mp4(out, keep_last(), fps, opts.width, opts.height)
    if opts.frame_png is not None and last:
        import imageio.v3 as iio

        Path(opts.frame_png).parent.mkdir(parents=True, exist_ok=True)
        iio.imwrite(opts.frame_png, last[0])
    return VideoInfo(out, count, fps, opts.width, opts.height, backend)


# -------------------------------------------------------------------------------------------- sources
def motion_video(motion_file: str | Path, char_file: str | Path, out: str | Path, opts: VideoOptions) -> VideoInfo:
    """A clip played kinematically on the MJCF character `char_file` (of a dataset yaml, its first clip)."""
    out = Path(out)
    _check_output(out, opts)
    backend = select_gl_backend()
    # The env's episode length is unused here: ViewMotionEnv ends episodes by clip length, and we never reset.
    fields = {"env_name": "view_motion", "char_file": str(char_file), "motion_file": str(motion_file)}
    env_cfg = parse_config(ViewMotionEnvConfig, {**fields, "episode_length": opts.seconds}, "mimickit video")
    engine_cfg = load_config(EngineConfig, PROJECT_DATA_DIR / "engines" / "mujoco_engine.yaml")
    env = ViewMotionEnv(env_cfg, engine_cfg, 1, "cpu", data_paths=opts.data_paths)
    try:
        view = env.engine.mujoco_view(0)
        model, char = view.model, view.objects[env.get_char_id()].body_ids
        model.geom_rgba[np.isin(model.geom_bodyid, char), :3] = CHAR_COLOR  # the policy video's colour
        fps = 1.0 / env.engine.get_timestep()
        renderer = TrackingRenderer(model, opts.width, opts.height, int(char[0]), None, stand_in_bones(model, char))
        frames = _motion_frames(env, renderer, opts.num_frames(fps))
        return _record(out, frames, fps, opts, backend)
    finally:
        env.engine.close()


def _motion_frames(env: CharEnv, renderer: TrackingRenderer, n: int) -> Iterator[np.ndarray]:
    action = torch.zeros(1, *env.get_action_space().shape)
    try:
        env.reset()
        yield renderer.render(_synced(env))
        for _ in range(n - 1):
            env.step(action)  # the clip wraps or holds its last frame past the end; never reset
            yield renderer.render(_synced(env))
    finally:
        renderer.close()


def policy_video(
    model_file: str | Path, arg_file: str | Path, out: str | Path, opts: VideoOptions, seed: int = 0
) -> VideoInfo:
    """The deterministic policy of `model_file` in the env and agent of `arg_file` (one env)."""
    out = Path(out)
    _check_output(out, opts)
    paths = opts.data_paths
    args = ArgParser(paths)
    args.load_args(["--arg_file", str(arg_file), "--rand_seed", str(seed)])
    inputs = resolve_inputs(args, paths)  # the configs and the arg file's --motion_file
    backend = select_gl_backend()
    seed_everything(args, 0)  # same seed, same start time in the clip, same video
    env, agent = load_policy(inputs, model_file, visualize=True)  # visualize: the env adds the ghost
    try:
        agent.set_mode(AgentMode.TEST)  # the env in test mode too, as `mimickit test`
        view, ghost_id = env.engine.mujoco_view(0), env.get_ref_char_id()
        model, char = view.model, view.objects[env.get_char_id()].body_ids
        ghost = view.objects[ghost_id].body_ids if ghost_id is not None else np.zeros(0, dtype=np.int64)
        make_ghost(model, ghost)
        ghost_root = int(ghost[0]) if len(ghost) else None
        bones = stand_in_bones(model, char) + stand_in_bones(model, ghost)
        renderer = TrackingRenderer(model, opts.width, opts.height, int(char[0]), ghost_root, bones)
        fps = 1.0 / env.engine.get_timestep()
        return _record(out, _policy_frames(env, agent, renderer, opts.num_frames(fps)), fps, opts, backend)
    finally:
        env.engine.close()


def _policy_frames(env: CharEnv, agent: BaseAgent, renderer: TrackingRenderer, n: int) -> Iterator[np.ndarray]:
    try:
        obs, _ = env.reset()
        yield renderer.render(_synced(env))
        for _ in range(n - 1):
            obs, _, done, _ = env.step(agent.compute_action(obs, deterministic=True))  # no_grad inside
            yield renderer.render(_synced(env))
            ended = torch.nonzero(done).flatten()
            if len(ended):  # a fall or timeout starts a new episode, as in `mimickit test`
                obs, _ = env.reset(ended)
    finally:
        renderer.close()


def _synced(env: CharEnv) -> mujoco.MjData:
    """Env 0's MjData with every pose the env has set (the ghost's pose, a reset): the engine's view."""
    return env.engine.mujoco_view(0).data
