"""A task env's target in the studio's rollout (issue 37, method-aware views): the AMP location and steering
envs declare `ShowsTaskTarget`, each recorded frame carries env 0's target, the rollout state gives the
target of the frame shown, the 3D view draws the env's marker where the target is, and the page's label says
it. Checkpoints come from the real trainer (one tiny iteration of each arg file, MimicKit's clips).
STUDIO_UPDATE_SCREENSHOTS=1 writes docs/studio_task_target.png (1280×720)."""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from mimickit.envs.viewable import ShowsTaskTarget
from mimickit.util.paths import PROJECT_ROOT
from studio.scene.rollout import Rollout, source_for_checkpoint
from tests.studio.conftest import CHROMIUM, StudioProcess, scene_page, wait_for
from tests.studio.test_e2e_browser import HIDE_TOAST

pytestmark = pytest.mark.integration
ARGS = {"location": "args/amp_location_humanoid_cpu_args.txt", "steering": "args/amp_steering_humanoid_args.txt"}


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory, test_data: Path) -> dict[str, Path]:
    """model.pt of one 4-env iteration of each task's arg file."""
    out = {}
    for kind, arg_file in ARGS.items():
        run = tmp_path_factory.mktemp(kind) / "run"
        cmd = [sys.executable, "-m", "mimickit.cli", "train", "--arg_file", arg_file, "--data_dir", str(test_data)]
        cmd += ["--num_envs", "4", "--max_samples", "128", "--out_dir", str(run), "--rand_seed", "0"]
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=PROJECT_ROOT)
        assert done.returncode == 0, done.stderr[-2000:]
        out[kind] = run / "model.pt"
    return out


@pytest.fixture
def rollout(request: pytest.FixtureRequest, runs: dict[str, Path], test_data: Path) -> Iterator[Rollout]:
    r = Rollout(source_for_checkpoint(runs[request.param], fallback_data_dir=test_data), history_s=2.0)
    yield r
    r.close()


def marker_xy(r: Rollout, frame) -> np.ndarray:
    xpos, _ = r.pose(frame)
    body = r.env.engine.mujoco_view(0).objects[r.env.get_marker_id()].body_ids[0]
    return xpos[body, :2]


@pytest.mark.parametrize("rollout", ["location"], indirect=True)
def test_a_location_rollout_records_its_target_and_draws_the_marker_there(rollout: Rollout) -> None:
    r = rollout
    assert isinstance(r.env, ShowsTaskTarget)
    for _ in range(10):
        frame = r.step()
    t = frame.task
    tar = r.env.get_tar_pos()[0]
    root = r.env.engine.get_root_pos(r.env.get_char_id())[0]
    assert t["kind"] == "location" and (t["x"], t["y"]) == pytest.approx((float(tar[0]), float(tar[1])), abs=1e-3)
    assert t["distance_m"] == pytest.approx(float((tar[:2] - root[:2]).norm()), abs=1e-3)
    np.testing.assert_allclose(marker_xy(r, frame), [t["x"], t["y"]], atol=1e-3)  # the marker the view draws


@pytest.mark.parametrize("rollout", ["steering"], indirect=True)
def test_a_steering_rollout_records_its_commanded_heading_and_speed(rollout: Rollout) -> None:
    r = rollout
    for _ in range(10):
        frame = r.step()
    t, targets = frame.task, r.env.get_targets()
    d = targets["tar_dir"][0]
    assert t["kind"] == "steering"
    assert t["heading_deg"] == pytest.approx(math.degrees(math.atan2(float(d[1]), float(d[0]))), abs=0.05)
    assert t["speed_mps"] == pytest.approx(float(targets["tar_speed"][0]), abs=1e-3)
    # The marker: an arrow ahead of the root along the commanded direction (task_steering_env.MARKER_LEAD).
    root = r.env.engine.get_root_pos(r.env.get_char_id())[0, :2]
    ahead = (marker_xy(r, frame) - root.numpy()) @ d.numpy()
    assert ahead == pytest.approx(1.0, abs=0.05)


@pytest.mark.browser
@pytest.mark.skipif(CHROMIUM is None, reason="no chromium on PATH (apt-get install chromium)")
def test_the_page_labels_a_task_rollout_with_its_target(runs: dict[str, Path], test_data: Path, tmp_path: Path,
                                                        browser) -> None:  # fmt: skip
    run = shutil.copytree(runs["location"].parent, tmp_path / "runs" / "location")  # inside the runs folder
    server = StudioProcess(tmp_path / "runs", test_data)
    try:
        page = scene_page(browser, server.url, 1280, 720)
        r = server.post("/api/scene/load_rollout", {"checkpoint": str(run / "model.pt")})
        assert r.status_code == 200, r.text
        s = wait_for(lambda: (st := server.get("/api/scene/state").json())["rollout"]["task"] and st, 60, "a target")
        assert s["rollout"]["task"]["kind"] == "location"
        label = page.locator("#rollout-task")
        wait_for(lambda: "m away" in label.inner_text(), 60, lambda: f"the target in {label.inner_text()!r}", page)
        assert label.inner_text().startswith("target (")
        if os.environ.get("STUDIO_UPDATE_SCREENSHOTS") == "1":  # the marker and the label, docs/studio.md
            page.locator("#scene").element_handle().content_frame().add_style_tag(content=HIDE_TOAST)
            page.screenshot(path=str(PROJECT_ROOT / "docs" / "studio_task_target.png"))
        page.close()
    finally:
        server.stop()
