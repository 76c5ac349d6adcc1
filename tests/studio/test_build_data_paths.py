"""Studio builds from request threads: each resolves `data/...` in its own data folder, at the same time."""

from __future__ import annotations

import shutil
import threading
from pathlib import Path

import mujoco  # noqa: F401  (at collection: importing it probes GLFW in a child process)
import pytest

from mimickit.util.paths import PROJECT_DATA_DIR
from studio.runs.checkpoints import env_spaces

ARM = """<mujoco><worldbody><body name="torso" pos="0 0 1"><freejoint/><geom type="box" size=".1 .1 .1" mass="2"/>
  <body name="link"><joint name="elbow" type="hinge" axis="0 1 0" stiffness="50" damping="5"
   actuatorfrcrange="-20 20"/><geom type="capsule" fromto="0 0 0 .3 0 0" size=".03" mass="0.5"/>
  </body></body></worldbody></mujoco>"""
ENV = "env_name: char\nchar_file: data/assets/char/char.xml\nglobal_obs: false\nepisode_length: 5.0\n"
ENGINE = PROJECT_DATA_DIR / "engines" / "mujoco_engine.yaml"
HUMANOID_DOFS = 28
ROUNDS = 2

pytestmark = pytest.mark.slow  # four env builds, two at a time


def data_folder(root: Path, char_xml: str | None) -> Path:
    """A data folder whose `assets/char/char.xml` is `char_xml` (the project's humanoid when None)."""
    target = root / "assets" / "char" / "char.xml"
    target.parent.mkdir(parents=True)
    if char_xml is None:
        shutil.copy(PROJECT_DATA_DIR / "assets" / "humanoid" / "humanoid.xml", target)
    else:
        target.write_text(char_xml)
    return root


def test_two_builds_at_once_resolve_data_paths_in_their_own_data_folders(tmp_path: Path) -> None:
    folders = {"humanoid": data_folder(tmp_path / "a", None), "arm": data_folder(tmp_path / "b", ARM)}
    start = threading.Barrier(len(folders))
    actions: dict[str, list[int]] = {name: [] for name in folders}
    errors: list[BaseException] = []

    def build(name: str) -> None:
        try:
            for r in range(ROUNDS):
                env_file = tmp_path / f"{name}_{r}.yaml"  # a new file each round: no cached sizes
                env_file.write_text(ENV)
                start.wait(timeout=60)
                actions[name].append(env_spaces(env_file, ENGINE, folders[name])[1])
        except BaseException as e:  # reported by the main thread
            errors.append(e)
            start.abort()

    threads = [threading.Thread(target=build, args=(name,)) for name in folders]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=300)
    assert not errors, errors
    assert actions == {"humanoid": [HUMANOID_DOFS] * ROUNDS, "arm": [1] * ROUNDS}
