"""The rollout's controls in viser's panel: what is rolled out, play/pause, step, new episode, the
history slider (scrub back), camera follow, a readout of the step, and a live uPlot chart of each
reward term over the last seconds. Shown while a rollout is loaded, in place of the clip player.

Like the player GUI, values assigned by the server fire callbacks with `event.client` None; those
are ignored. GUI updates are throttled (the rollout draws 30 times a second).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import viser

from studio.rollout import RolloutPlayer

REFRESH_S = 0.2  # readout, slider and chart are re-sent at most 5 times a second while playing
PLOT_WINDOW_S = 10.0
TERM_COLORS = ["#f0a830", "#5a9ae0", "#3cc878", "#e0564f", "#b77fe0", "#40c8c8", "#e07fb0", "#a0a060"]


class RolloutGui:
    def __init__(self, server: viser.ViserServer, player_folders: list[viser.GuiFolderHandle] | None = None) -> None:
        """`player_folders`: the clip player's folders, hidden while a rollout is shown."""
        self.server = server
        self.player_folders = player_folders or []
        self.rp: RolloutPlayer | None = None
        self._last = 0.0
        self._plot: viser.GuiUplotHandle | None = None
        self._series: list[str] = []
        gui = server.gui
        self.folder = gui.add_folder("Rollout", visible=False)
        with self.folder:
            self.title = gui.add_markdown("")
            self.play_button = gui.add_button("Play", icon=viser.Icon.PLAYER_PLAY)
            self.step_button = gui.add_button("Step", icon=viser.Icon.PLAYER_TRACK_NEXT)
            self.reset_button = gui.add_button("New episode", icon=viser.Icon.REFRESH)
            self.history = gui.add_slider("History", min=0, max=1, step=1, initial_value=0)
            self.follow = gui.add_checkbox("Camera follow", initial_value=True)
            self.readout = gui.add_markdown("")
        self.play_button.on_click(lambda _: self._do(lambda rp: rp.toggle()))
        self.step_button.on_click(lambda _: self._do(lambda rp: rp.step(1)))
        self.reset_button.on_click(lambda _: self._do(lambda rp: rp.reset()))
        self.history.on_update(self._from_client(lambda rp, v: rp.seek(frame=int(v))))
        self.follow.on_update(self._from_client(lambda rp, v: rp.configure(follow=bool(v))))

    def _do(self, fn) -> None:  # noqa: ANN001
        if self.rp is not None:
            fn(self.rp)

    def _from_client(self, fn):  # noqa: ANN001, ANN205 (an adapter for viser's event callbacks)
        def callback(event: viser.GuiEvent) -> None:
            if event.client is not None and self.rp is not None:
                fn(self.rp, event.target.value)

        return callback

    def attach(self, rp: RolloutPlayer) -> None:
        """Show the controls for `rp` (and hide the clip player's)."""
        self.rp = rp
        r = rp.rollout
        src = r.source
        what = Path(src.checkpoint).name
        if src.run_id is not None:
            what = f"run #{src.run_id} {src.run_name or ''}".strip()
        self.title.content = (
            f"**{what}**  \n{Path(src.checkpoint).name} · {Path(src.env_config).name} · {r.control_freq:g} Hz  \n"
            "*green, translucent: the reference clip (ghost)*"
        )
        names = list(r.reward_weights) or []
        self._series = names
        if self._plot is not None:
            self._plot.remove()
        series = [{"label": "t (s)"}, {"label": "reward", "stroke": "#ffffff", "width": 2}]
        series += [{"label": n, "stroke": TERM_COLORS[i % len(TERM_COLORS)], "width": 1.5} for i, n in enumerate(names)]
        with self.folder:
            self._plot = self.server.gui.add_uplot(
                data=tuple(np.zeros(0) for _ in series),
                series=tuple(series),
                title="reward terms (unweighted) and reward",
                scales={"x": {"time": False}, "y": {"auto": False, "range": (0.0, 1.0)}},
                aspect=1.6,
            )
        self.folder.visible = True
        for f in self.player_folders:
            f.visible = False
        rp.add_listener(self.refresh)
        self._last = 0.0
        self.refresh(rp)

    def detach(self) -> None:
        self.rp = None
        self.folder.visible = False
        if self._plot is not None:
            self._plot.remove()
            self._plot = None
        for f in self.player_folders:
            f.visible = True

    def refresh(self, rp: RolloutPlayer) -> None:
        """Mirror the rollout into the GUI (called after each drawn step or change; throttled)."""
        if rp is not self.rp:
            return
        s = rp.state
        now = time.monotonic()
        if s.playing and now - self._last < REFRESH_S:
            return
        self._last = now
        snap = rp.snapshot()
        info = snap["rollout"]
        self.play_button.label = "Pause" if s.playing else "Play"
        self.play_button.icon = viser.Icon.PLAYER_PAUSE if s.playing else viser.Icon.PLAYER_PLAY
        self.history.max = max(1, snap["num_frames"] - 1)
        self.history.value = snap["frame"]
        self.follow.value = s.follow
        shown = info["shown"]
        reward = "–" if shown["reward"] is None else f"{shown['reward']:.3f}"
        terms = " · ".join(f"{k} {v:.2f}" for k, v in shown["reward_terms"].items())
        lines = [
            f"step {shown['step']} · episode {shown['episode']} (step {shown['episode_step']})"
            + ("" if info["live"] else " · *history*"),
            f"return {shown['episode_return']:.2f} · reward {reward}",
            terms,
        ]
        if info["episodes"]:
            last = info["episodes"][-1]
            lines.append(f"last episode: {last['steps']} steps, return {last['return']:.2f}")
        if info["error"]:
            lines.append(f"**{info['error']}**")
        self.readout.content = "  \n".join(line for line in lines if line)
        self._update_plot(rp)

    def _update_plot(self, rp: RolloutPlayer) -> None:
        if self._plot is None:
            return
        rows = rp.history_rows()
        if rows:
            t_end = rows[-1]["time"]
            rows = [r for r in rows if r["time"] >= t_end - PLOT_WINDOW_S]
        x = np.array([r["time"] for r in rows], dtype=np.float64)
        cols = [x, np.array([r["reward"] for r in rows], dtype=np.float64)]
        cols += [np.array([r["terms"].get(n, np.nan) for r in rows], dtype=np.float64) for n in self._series]
        self._plot.data = tuple(cols)
