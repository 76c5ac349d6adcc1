"""Replays: a clip or a policy rollout as one HTML file that plays offline in any browser.

How: a private viser server (loopback, a free port; no browser ever connects to it) holds a
`StudioScene`, so a replay is drawn exactly as the live studio draws (colours, ground, root path,
foot contacts, the rollout's ghost). viser's scene serializer records the scene's messages with a
sleep of one frame between poses; `as_html` puts the recording (zstd-compressed, base64) into
viser's prebuilt client page, which reads it from `window.__VISER_EMBED_DATA__`. The result is one
self-contained file (viser's client, ~0.8 MB, plus the recording): no server, no network, opens from
`file://`, with viser's playback bar (play/pause, timeline, speed). Output ending in `.viser` is the
raw recording instead (viser's own player page fetches it with `?playbackPath=`, over http only).

Shapes: a rollout's frames are MuJoCo `qpos` vectors [nq] of its env model.
"""

from __future__ import annotations

import contextlib
import io
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from mimickit.util.errors import MimicKitError
from mimickit.util.paths import atomic_write_bytes, check_output_file
from studio.scene.clip_pose import ClipPose, pose_clip
from studio.scene.proxy import guarded_viser_server
from studio.scene.rollout import Rollout, RolloutPlayer, RolloutSource
from studio.scene.view import StudioScene

MAX_REPLAY_HZ = 60.0  # as the live player: a 120 fps clip is recorded every other frame
MAX_REPLAY_FRAMES = 36_000  # 10 min at 60 Hz: beyond that a file gets too big to open comfortably
SUFFIXES = (".html", ".viser")


@dataclass
class ReplayInfo:
    path: Path
    kind: str  # "clip" or "rollout"
    frames: int  # poses recorded
    fps: float  # poses per second of playback
    duration: float  # seconds
    bytes: int

    def to_json(self) -> dict[str, Any]:
        return {
            "path": str(self.path),
            "kind": self.kind,
            "frames": self.frames,
            "fps": self.fps,
            "duration": self.duration,
            "bytes": self.bytes,
        }


@contextlib.contextmanager
def offline_scene() -> Iterator[StudioScene]:
    """A `StudioScene` on a private viser server, stopped afterwards. Its port refuses every request, as
    the studio's own viser port refuses all but the relay's: nothing is meant to connect to it."""
    with contextlib.redirect_stdout(io.StringIO()):  # viser prints a banner and "Server stopped"
        server = guarded_viser_server(host="127.0.0.1", port=0, verbose=False)
    try:
        yield StudioScene(server)
    finally:
        with contextlib.redirect_stdout(io.StringIO()):
            server.stop()


def check_output(out: str | Path) -> Path:
    """`out` if a replay can be written there: its suffix, a folder that is not a system one, and
    nothing but a regular file in its place (checked before any work); MimicKitError otherwise."""
    p = Path(out)
    shown = str(p)[:200]
    if p.suffix.lower() not in SUFFIXES:
        raise MimicKitError(f"replay output must end in .html (standalone page) or .viser (recording), got {shown}")
    return check_output_file(p, "replay output")


def frame_stride(fps: float, max_hz: float = MAX_REPLAY_HZ) -> int:
    """Record every n-th frame so that playback sends at most `max_hz` poses a second."""
    return max(1, math.ceil(fps / max_hz - 1e-9))


def export_clip_replay(
    clip: str | Path, char: str | Path, out: str | Path, *, follow: bool = True, max_hz: float = MAX_REPLAY_HZ
) -> ReplayInfo:
    """Write a replay of `clip` posed on the MJCF `char`."""
    out = check_output(out)
    return write_clip_replay(pose_clip(Path(clip), Path(char)), out, follow=follow, max_hz=max_hz)


def write_clip_replay(
    pose: ClipPose, out: str | Path, *, follow: bool = True, max_hz: float = MAX_REPLAY_HZ
) -> ReplayInfo:
    out = check_output(out)
    stride = frame_stride(pose.fps, max_hz)
    frames = list(range(0, pose.num_frames, stride))
    if frames[-1] != pose.num_frames - 1:
        frames.append(pose.num_frames - 1)  # the last pose, even when the stride steps over it
    frames = frames[:MAX_REPLAY_FRAMES]
    with offline_scene() as scene:
        scene.show_clip(pose)
        scene.draw(pose, frames[0], follow)
        recorder = scene.server.get_scene_serializer()  # the scene so far, then every pose
        for i, f in enumerate(frames):
            if i:
                recorder.insert_sleep((f - frames[i - 1]) / pose.fps)  # clip time: the replay keeps its duration
            scene.draw(pose, f, follow)
        size = _save(recorder, out)
    duration = (frames[-1] - frames[0]) / pose.fps
    return ReplayInfo(out, "clip", len(frames), pose.fps / stride, duration, size)


@dataclass
class RolloutFrames:
    """What a rollout replay needs: the env's model, which bodies are the ghost, and the recorded qpos."""

    model: mujoco.MjModel
    ghost_bodies: np.ndarray
    root_body: int
    ghost_root: int | None
    dt: float
    qpos: Sequence[np.ndarray]


def rollout_frames(rollout: Rollout, qpos: Sequence[np.ndarray] | None = None) -> RolloutFrames:
    """`rollout`'s model with `qpos` (default: its recorded history, the last `HISTORY_S` seconds)."""
    return RolloutFrames(
        rollout.model,
        rollout.ghost_bodies,
        rollout.root_body,
        rollout.ghost_root,
        rollout.dt,
        [f.qpos.copy() for f in rollout.history] if qpos is None else list(qpos),
    )


def write_rollout_replay(rf: RolloutFrames, out: str | Path, *, follow: bool = True) -> ReplayInfo:
    out = check_output(out)
    qpos = list(rf.qpos)[-MAX_REPLAY_FRAMES:]
    if not qpos:
        raise MimicKitError("the rollout has no recorded steps yet")
    data = mujoco.MjData(rf.model)  # our own: the live rollout keeps drawing with its scratch data
    with offline_scene() as scene:
        scene.show_rollout(rf.model, rf.ghost_bodies)
        recorder = None
        for i, q in enumerate(qpos):
            data.qpos[:] = q
            mujoco.mj_kinematics(rf.model, data)
            root = data.xpos[rf.root_body]
            # As the live rollout: following keeps the character and its ghost in view.
            centre = root if rf.ghost_root is None else 0.5 * (root + data.xpos[rf.ghost_root])
            if recorder is None:
                scene.draw_bodies(data.xpos.copy(), data.xmat.copy(), centre, follow)
                recorder = scene.server.get_scene_serializer()
            if i:
                recorder.insert_sleep(rf.dt)
            scene.draw_bodies(data.xpos.copy(), data.xmat.copy(), centre, follow)
        size = _save(recorder, out)
    return ReplayInfo(out, "rollout", len(qpos), 1.0 / rf.dt, (len(qpos) - 1) * rf.dt, size)


def export_player_rollout(rp: RolloutPlayer, out: str | Path, *, follow: bool = True) -> ReplayInfo:
    """A replay of what the studio's live rollout has recorded (its timeline)."""
    rf = rollout_frames(rp.rollout, rp.history_qpos())  # copied under the player's lock: it keeps stepping
    return write_rollout_replay(rf, out, follow=follow)


def export_policy_replay(source: RolloutSource, out: str | Path, *, seconds: float = 10.0) -> ReplayInfo:
    """Roll the deterministic policy of `source.checkpoint` out for `seconds` (an episode that ends
    starts again, as in the studio) and write its replay."""
    out = check_output(out)
    if not 0 < seconds <= MAX_REPLAY_FRAMES / MAX_REPLAY_HZ:
        raise MimicKitError(f"--seconds must be in (0, {MAX_REPLAY_FRAMES / MAX_REPLAY_HZ:g}], got {seconds}")
    rollout = Rollout(source, history_s=seconds + 1.0)
    try:
        for _ in range(round(seconds / rollout.dt)):
            rollout.step()
        rf = rollout_frames(rollout)
    finally:
        rollout.close()
    return write_rollout_replay(rf, out)


def _save(recorder: Any, out: Path) -> int:
    # .html: viser's client page with the recording inlined, in the studio's dark theme.
    data = recorder.serialize() if out.suffix.lower() == ".viser" else recorder.as_html(dark_mode=True).encode()
    try:
        atomic_write_bytes(out, data)
    except OSError as e:  # a folder that cannot be made or written, a full disk: one line, not a traceback
        raise MimicKitError(f"{str(out)[:200]}: cannot write the replay ({e.strerror or e})") from None
    return len(data)
