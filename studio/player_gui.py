"""The player's controls in viser's own panel (inside the embedded scene): play/pause, step, timeline,
speed, loop, camera follow, a joint-value readout, and the MimicKit keys (Enter: play/pause, Space:
step one frame).

Assigning a GUI value on the server fires its callbacks too (event.client is None); those are
ignored so that the player moving the timeline does not seek itself.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import viser

from studio.player import MAX_SPEED, MIN_SPEED, Player

READOUT_PERIOD_S = 0.2  # the joint table is re-sent at most 5 times a second while playing


class PlayerGui:
    def __init__(self, server: viser.ViserServer, player: Player, active: Callable[[], Any] | None = None) -> None:
        """`active()`: what the keys drive (the clip player, or a rollout while one is loaded)."""
        self.player = player
        active = active or (lambda: player)
        self._last_readout = 0.0
        self._shown: object = None  # the ClipPose the title and timeline range describe
        gui = server.gui
        gui.configure_theme(dark_mode=True, control_layout="floating", show_share_button=False)
        self.folder = gui.add_folder("Player")
        with self.folder:
            self.title = gui.add_markdown("*no clip loaded: pick one in the library*")
            self.play_button = gui.add_button("Play", icon=viser.Icon.PLAYER_PLAY)
            self.step_button = gui.add_button("Step one frame", icon=viser.Icon.PLAYER_TRACK_NEXT)
            self.timeline = gui.add_slider("Frame", min=0, max=1, step=1, initial_value=0)
            self.speed = gui.add_slider("Speed", min=MIN_SPEED, max=MAX_SPEED, step=0.05, initial_value=1.0)
            self.loop = gui.add_checkbox("Loop", initial_value=True)
            self.follow = gui.add_checkbox("Camera follow", initial_value=True)
        self.readout_folder = gui.add_folder("Joint values (rad)")
        with self.readout_folder:
            self.readout = gui.add_markdown("")
        # Hotkeys work while the pointer/focus is in the scene; the dashboard page handles them elsewhere.
        gui.add_command("Play / pause", hotkey="enter").on_trigger(lambda _: active().toggle())
        gui.add_command("Step one frame", hotkey="space").on_trigger(lambda _: active().step(1))

        self.play_button.on_click(lambda _: player.toggle())
        self.step_button.on_click(lambda _: player.step(1))
        self.timeline.on_update(self._from_client(lambda v: player.seek(frame=int(v))))
        self.speed.on_update(self._from_client(lambda v: player.configure(speed=v)))
        self.loop.on_update(self._from_client(lambda v: player.configure(loop=v)))
        self.follow.on_update(self._from_client(lambda v: player.configure(follow=v)))
        player.add_listener(self.refresh)

    @staticmethod
    def _from_client(fn):  # noqa: ANN001, ANN205 (a tiny adapter for viser's event callbacks)
        def callback(event: viser.GuiEvent) -> None:
            if event.client is not None:
                fn(event.target.value)

        return callback

    def refresh(self, player: Player) -> None:
        """Mirror the player's state into the GUI (called by the player after each change)."""
        pose, s = player.pose, player.state
        if pose is None:
            return
        if self._shown is not pose:
            self._shown = pose
            self.timeline.max = max(1, pose.num_frames - 1)
            self.title.content = (
                f"**{pose.path.name}** on {pose.char_path.name}  \n{pose.num_frames} frames at {pose.fps:g} fps"
            )
        self.timeline.value = s.frame
        self.speed.value = s.speed
        self.loop.value = s.loop
        self.follow.value = s.follow
        self.play_button.label = "Pause" if s.playing else "Play"
        self.play_button.icon = viser.Icon.PLAYER_PAUSE if s.playing else viser.Icon.PLAYER_PLAY
        now = time.monotonic()
        if not s.playing or now - self._last_readout >= READOUT_PERIOD_S:
            self._last_readout = now
            self.readout.content = _joint_table(player, s.frame)


def _joint_table(player: Player, frame: int) -> str:
    pose = player.pose
    rows = [f"frame {frame} · {frame / pose.fps:.2f} s", "", "| joint | values |", "|---|---|"]
    for name, values in pose.joint_values(frame):
        rows.append(f"| {name} | {' '.join(f'{v:+.2f}' for v in values)} |")
    return "\n".join(rows)
