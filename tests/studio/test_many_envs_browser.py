"""Many envs at once in real Chromium (Playwright, the apt browser): pick the shipped demo model under
*Checkpoints*, 4 envs, grid, *Roll out*: the server's scene draws the four characters (env 0 and three
batched figures on their cells), the rollout label's per-env summary shows a cell per env with its falls,
and a fall of env 1 (pushed through the API) reaches its cell on the page.

No fixed sleeps: every check waits on its condition. STUDIO_UPDATE_SCREENSHOTS=1 writes the view to
docs/studio_many_envs.png (1280×720).
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from mimickit.util.paths import PROJECT_ROOT
from tests.studio.conftest import StudioProcess, wait_for
from tests.studio.test_body_error_browser import SHIPPED, page, server  # noqa: F401 - its server and page
from tests.studio.test_e2e_browser import HIDE_TOAST

pytestmark = pytest.mark.browser
WAIT_S = 90  # the scene's software WebGL shares the page's main thread


def envs(studio: StudioProcess) -> dict | None:
    r = studio.get("/api/scene/state").json().get("rollout")
    return r["envs"] if r else None


def test_four_envs_from_the_page(page, server: StudioProcess, tmp_path: Path) -> None:  # noqa: F811
    page.select_option("#checkpoint", value=SHIPPED)
    page.fill("#rollout-envs", "4")
    page.select_option("#rollout-layout", value="grid")
    page.click("#rollout-button")
    try:
        e = wait_for(lambda: (x := envs(server)) and x["num_envs"] == 4 and x, 60, "the rollout of 4 envs")
        assert e["layout"] == "grid" and e["drawn"]["bodies"] == 15 and len(e["drawn"]["at"]) == 3
        cells = page.locator("#rollout-envs-summary .env-cell")
        wait_for(lambda: cells.count() == 4, WAIT_S, "a summary cell per env")
        assert "4 envs (grid)" in page.locator("#rollout-envs-summary").inner_text()

        pushed = server.post("/api/scene/rollout/push", {"force": [0, 3000, 0], "duration_s": 0.5, "env": 1})
        assert pushed.status_code == 200, pushed.text
        wait_for(lambda: envs(server)["per_env"][1]["falls"] >= 1, WAIT_S, "env 1 to fall")
        fallen = page.locator("#rollout-envs-summary .env-cell[data-env='1']")
        wait_for(lambda: int(fallen.get_attribute("data-falls") or 0) >= 1, WAIT_S, "env 1's fall on the page")
        assert int(fallen.inner_text()) >= 1

        page.locator("#scene").element_handle().content_frame().add_style_tag(content=HIDE_TOAST)
        shot = PROJECT_ROOT / "docs" / "studio_many_envs.png"
        if os.environ.get("STUDIO_UPDATE_SCREENSHOTS") != "1":
            shot = tmp_path / "studio_many_envs.png"
        page.screenshot(path=str(shot))
    finally:
        page.click("#rollout-close")
    wait_for(lambda: server.get("/api/scene/state").json()["mode"] == "clip", WAIT_S, "back to clips")
    page.locator("#rollout-envs-summary").wait_for(state="hidden", timeout=WAIT_S * 1000)
    assert page.errors == []
