"""The server leaves the folder it was started from alone: it works in `<runs-dir>/studio/`, so the
`MUJOCO_LOG.TXT` that MuJoCo writes on a warning (here: a rollout whose physics blows up) lands there,
not in the user's checkout. A real `mimickit-studio serve` started with its cwd in a fresh folder."""

from __future__ import annotations

from pathlib import Path

import pytest

from studio.cli import SERVER_WORK_DIR
from tests.studio.conftest import ENGINE_YAML, ENV_YAML, StudioProcess, wait_for, write_checkpoint_dir

pytestmark = pytest.mark.integration
MUJOCO_LOG = "MUJOCO_LOG.TXT"


def unstable_engine_yaml() -> str:
    """The demo engine with one explicit-Euler substep per control step: the humanoid's PD gains blow
    the simulation up within a second, and MuJoCo warns (Nan, Inf or huge value in QACC)."""
    text = ENGINE_YAML.read_text()
    assert "sim_freq: 240" in text
    return text.replace("sim_freq: 240", "sim_freq: 30") + "\nintegrator: euler\n"


def endless_env_yaml() -> str:
    """The demo env without early termination: an untrained policy's episode lasts until the blow-up
    (with it, the character falls and resets within three steps, before the physics diverges)."""
    text = ENV_YAML.read_text()
    for key in ("enable_early_termination", "pose_termination"):
        assert f"{key}: True" in text
        text = text.replace(f"{key}: True", f"{key}: False")
    return text


def test_a_rollout_warning_is_logged_in_the_servers_own_folder(tmp_path: Path) -> None:
    start, runs = tmp_path / "start", tmp_path / "runs"
    start.mkdir()
    runs.mkdir()
    checkpoint = write_checkpoint_dir(runs / "unstable", endless_env_yaml())
    (checkpoint.parent / "engine_config.yaml").write_text(unstable_engine_yaml())
    server = StudioProcess(runs, None, "--clip", "none", cwd=start)
    try:
        r = server.post("/api/scene/load_rollout", {"checkpoint": str(checkpoint)})
        assert r.status_code == 200, r.text
        work_log = runs / SERVER_WORK_DIR / MUJOCO_LOG
        wait_for(work_log.is_file, 90, f"MuJoCo's warning in {work_log}")
        assert "The simulation is unstable" in work_log.read_text()
        assert server.get("/api/scene/state").json()["rollout"]["step"] > 0
    finally:
        server.stop()
    assert list(start.iterdir()) == [], "the server wrote into the folder it was started from"
