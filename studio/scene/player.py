"""The clip player: which frame of which clip is shown, advanced by the scene thread at clip fps × speed.

The state lives here on the server (one scene shared by every browser), so REST calls, the viser
GUI and the keyboard all drive the same player, and tests can read it back through the API.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

from studio.scene.clip_pose import ClipPose
from studio.scene.playable import Playable, command
from studio.scene.thread import SceneThread
from studio.scene.view import StudioScene

MAX_UPDATE_HZ = 60.0  # a 120 fps clip at speed 2 still sends at most this many scene updates a second
MIN_SPEED, MAX_SPEED = 0.05, 8.0
UNWATCHED_PERIOD_S = 1.0  # how often a playing clip is drawn while no browser shows the 3D view


@dataclass
class PlayerState:
    frame: int = 0
    time: float = 0.0
    playing: bool = False
    speed: float = 1.0
    loop: bool = True
    follow: bool = True
    updates: int = 0  # scene updates sent since start: the benchmark's frames-delivered counter


class Player(Playable):
    def __init__(self, scene: StudioScene, owner: SceneThread) -> None:
        super().__init__(owner)
        self.scene = scene
        self.pose: ClipPose | None = None
        self.state = PlayerState()
        self._root = [0.0, 0.0, 0.0]
        self._last = 0.0  # monotonic time the clock last advanced to

    # -- commands ---------------------------------------------------------------------------------

    @command
    def load(self, pose: ClipPose, *, play: bool = False) -> None:
        self.pose = pose
        self.scene.show_clip(pose)
        self.state.playing = play
        self._last = time.monotonic()
        self._seek_frame(0)

    @command
    def show(self) -> None:
        """Draw the clip again at its frame (the view dropped its character for a rollout)."""
        if self.pose is not None:
            self.scene.show_clip(self.pose)
            self._seek_frame(self.state.frame)

    @command
    def play(self) -> None:
        if self.pose is None:
            return
        if not self.state.loop and self.state.frame >= self.pose.num_frames - 1:
            self._seek_frame(0)  # play at the end of a non-looping clip starts it over
        if not self.state.playing:
            self._last = time.monotonic()
        self.state.playing = True
        self._changed()

    @command
    def step(self, frames: int = 1) -> None:
        """Pause and move `frames` (may be negative), wrapping when looping, else clamped."""
        if self.pose is None:
            return
        self.state.playing = False
        self._seek_frame(self._wrap_or_clamp(self.state.frame + frames))

    @command
    def seek(self, *, frame: int | None = None, time_s: float | None = None) -> None:
        if self.pose is None:
            return
        if frame is None:
            frame = round((time_s or 0.0) * self.pose.fps)
        self._seek_frame(max(0, min(int(frame), self.pose.num_frames - 1)))

    @command
    def configure(self, *, speed: float | None = None, loop: bool | None = None, follow: bool | None = None) -> None:
        if speed is not None:
            self.state.speed = min(max(float(speed), MIN_SPEED), MAX_SPEED)
        if loop is not None:
            self.state.loop = bool(loop)
        if follow is not None:
            self.state.follow = bool(follow)
            if self.pose is not None:
                self._draw()
        self._changed()

    def _snapshot(self) -> dict[str, Any]:
        """The player's state as the API reports it."""
        s = self.state
        pose = self.pose
        return {
            "mode": "clip",
            "clip": str(pose.path) if pose else None,
            "char": str(pose.char_path) if pose else None,
            "drawn": str(drawn) if (drawn := self.scene.drawn_character()) else None,  # what the 3D view shows
            "num_frames": pose.num_frames if pose else 0,
            "fps": pose.fps if pose else None,
            "duration": pose.motion.duration if pose else 0.0,
            "frame": s.frame,
            "time": s.time,
            "playing": s.playing,
            "speed": s.speed,
            "loop": s.loop,
            "follow": s.follow,
            "updates": s.updates,
            "root_pos": list(self._root),
            "contacts": dict(zip(pose.feet, pose.contacts(s.frame).tolist(), strict=True)) if pose else {},
        }

    # -- internals --------------------------------------------------------------------------------

    def _wrap_or_clamp(self, frame: int) -> int:
        n = self.pose.num_frames
        return frame % n if self.state.loop else max(0, min(frame, n - 1))

    def _seek_frame(self, frame: int) -> None:
        self.state.frame = frame
        self.state.time = frame / self.pose.fps
        self._draw()

    def _draw(self) -> None:
        pose = self.pose
        self.scene.draw(pose, self.state.frame, self.state.follow)
        self._root = pose.root_pos[self.state.frame].astype(float).tolist()
        self.state.updates += 1
        self._changed()

    def due(self) -> float | None:
        if not self.state.playing or self.pose is None:
            return None
        period = 1.0 / min(self.pose.fps * self.state.speed, MAX_UPDATE_HZ)
        if not self.scene.watched():  # the clock runs on, drawn seldom: an idle server costs no core share
            period = max(period, UNWATCHED_PERIOD_S)
        return self._last + period

    def tick(self, now: float) -> None:
        """Advance by the wall-clock time since the last tick; draw only when the frame index changes."""
        if self.state.playing and self.pose is not None:
            self._advance((now - self._last) * self.state.speed)
        self._last = now

    def _advance(self, dt: float) -> None:
        pose, s = self.pose, self.state
        duration = pose.motion.duration
        t = s.time + dt
        if t > duration:
            if s.loop and duration > 0:
                t = math.fmod(t, duration)
            else:
                t, s.playing = duration, False
        frame = min(round(t * pose.fps), pose.num_frames - 1)
        s.time = t
        if frame != s.frame or not s.playing:
            s.frame = frame
            self._draw()
