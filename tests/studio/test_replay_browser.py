"""An exported replay opened from `file://` in headless Chromium (Playwright, the apt browser), with
no server and no network: viser's client decodes the inlined recording, draws the character and
plays the timeline. Software WebGL fades the scene in over ~10-30 s on this machine, hence the polling.

STUDIO_UPDATE_SCREENSHOTS=1 writes the screenshot to docs/studio_replay.png.
"""

from __future__ import annotations

import io
import os
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

from mimickit.util.paths import PROJECT_ROOT
from studio.scene.replay import export_clip_replay
from tests.conftest import DEMO_CLIP, PROJECT_HUMANOID

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install playwright)")
Image = pytest.importorskip("PIL.Image")

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(CHROMIUM is None, reason="no chromium on PATH (apt-get install chromium)"),
]
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking"]


def coloured_fraction(png: bytes) -> float:
    """Share of pixels in the character's side colours (coral right, blue left): the dark ground and
    grid are grey, so these appear only where the character is drawn."""
    rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int32)
    r, b = rgb[..., 0], rgb[..., 2]
    coral = (r > 150) & (r - b > 60)
    blue = (b > 140) & (b - r > 50)
    return float((coral | blue).mean())


def test_exported_replay_plays_offline_in_chromium(tmp_path: Path) -> None:
    out = tmp_path / "squat.html"
    export_clip_replay(DEMO_CLIP, PROJECT_HUMANOID, out)
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=ARGS)
        page = browser.new_page(viewport={"width": 900, "height": 600})
        errors: list[str] = []
        console: list[str] = []
        remote: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.on("console", lambda m: console.append(m.text))
        page.on("request", lambda r: remote.append(r.url) if r.url.startswith("http") else None)
        page.goto(out.as_uri())
        page.locator("canvas").first.wait_for(timeout=60_000)
        png, fraction, deadline = b"", 0.0, time.monotonic() + 120
        while time.monotonic() < deadline:
            png = page.locator("canvas").first.screenshot()
            fraction = coloured_fraction(png)
            if fraction > 0.002:
                break
            time.sleep(2.0)
        clock = later = page.locator("input").first.input_value()  # the playback bar's time readout
        deadline = time.monotonic() + 60  # a loaded machine can hold the page for seconds: no fixed window
        while later == clock and time.monotonic() < deadline:
            time.sleep(0.5)
            later = page.locator("input").first.input_value()
        if os.environ.get("STUDIO_UPDATE_SCREENSHOTS"):
            # viser's "Software WebGL rendering detected" notice says nothing about the replay.
            page.add_style_tag(content="[class*=Notification-root] { display: none !important; }")
            time.sleep(2.0)
            page.screenshot(path=str(PROJECT_ROOT / "docs" / "studio_replay.png"))
        browser.close()
    assert not errors, errors
    assert not remote, f"the replay fetched from the network: {remote}"
    assert any("Embedded data loaded" in line for line in console), console
    assert fraction > 0.002, f"no character pixels after 120 s ({fraction:.4%} coloured)"
    assert clock != later, f"the playback clock did not move ({clock!r})"
