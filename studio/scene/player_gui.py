"""What the embedded viser page keeps of its own GUI: nothing on screen. The dashboard page is the one
control surface (player bar, rollout panel, runs); viser's control panel would cover the character.

Only the MimicKit keys stay registered in viser (Enter: play/pause, Space: step one frame), as
commands without a panel: while the pointer has clicked into the 3D view, the keys go to the scene's
iframe, not to the dashboard's document, and these commands make them work there too.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import viser


class SceneKeys:
    def __init__(self, server: viser.ViserServer, active: Callable[[], Any]) -> None:
        """`active()`: what the keys drive (the clip player, or a rollout while one is loaded)."""
        gui = server.gui
        gui.configure_theme(dark_mode=True, show_logo=False, show_share_button=False)
        gui.main_panel.minimize()
        gui.add_command("Play / pause", hotkey="enter").on_trigger(lambda _: active().toggle())
        gui.add_command("Step one frame", hotkey="space").on_trigger(lambda _: active().step(1))
