"""`DataPaths`: where `data/...` and other relative paths are found, for one data folder."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from mimickit.util.paths import PROJECT_DATA, PROJECT_DATA_DIR, PROJECT_ROOT, DataPaths

HUMANOID = Path("data/assets/humanoid/humanoid.xml")  # in the project's data


@pytest.fixture
def user_data(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A user's data folder shadowing the project's humanoid; the working folder is a scratch one."""
    folder = tmp_path / "mimickit_data"
    (folder / "assets" / "humanoid").mkdir(parents=True)
    (folder / "assets" / "humanoid" / "humanoid.xml").write_text("<mujoco/>")
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    return folder


def test_data_paths_look_in_the_users_folder_then_the_projects_then_the_working_folder(
    user_data: Path, tmp_path: Path
) -> None:
    paths = DataPaths(user_data)
    assert paths.dirs() == [user_data.resolve(), PROJECT_DATA_DIR]
    assert paths.resolve(HUMANOID) == user_data.resolve() / "assets/humanoid/humanoid.xml"
    assert PROJECT_DATA.resolve(HUMANOID) == PROJECT_DATA_DIR / "assets/humanoid/humanoid.xml"
    assert paths.resolve("data/engines/mujoco_engine.yaml") == PROJECT_DATA_DIR / "engines/mujoco_engine.yaml"
    only_here = tmp_path / "work" / "data" / "mine.yaml"
    only_here.parent.mkdir()
    only_here.write_text("x: 1")
    assert paths.resolve("data/mine.yaml") == only_here


def test_other_relative_paths_look_in_the_working_folder_first_then_the_data_folders_then_the_project(
    user_data: Path, tmp_path: Path
) -> None:
    paths = DataPaths(user_data)
    assert paths.resolve("assets/humanoid/humanoid.xml") == user_data.resolve() / "assets/humanoid/humanoid.xml"
    assert paths.resolve("args/deepmimic_humanoid_demo_ppo_args.txt") == (
        PROJECT_ROOT / "args/deepmimic_humanoid_demo_ppo_args.txt"
    )
    mine = tmp_path / "work" / "assets" / "humanoid" / "humanoid.xml"
    mine.parent.mkdir(parents=True)
    mine.write_text("<mujoco/>")
    assert paths.resolve("assets/humanoid/humanoid.xml") == mine


def test_absolute_paths_are_returned_as_given_and_a_missing_file_names_the_first_place_looked(
    user_data: Path, tmp_path: Path
) -> None:
    paths = DataPaths(user_data)
    absent = tmp_path / "nowhere" / "clip.pkl"
    assert paths.resolve(absent) == absent
    assert (
        paths.resolve(str(PROJECT_DATA_DIR / HUMANOID.relative_to("data")))
        == PROJECT_DATA_DIR / "assets/humanoid/humanoid.xml"
    )
    assert paths.resolve("data/motions/missing.pkl") == user_data.resolve() / "motions/missing.pkl"
    assert PROJECT_DATA.resolve("data/motions/missing.pkl") == PROJECT_DATA_DIR / "motions/missing.pkl"
    assert paths.resolve("motions/missing.pkl") == tmp_path / "work" / "motions/missing.pkl"


def test_no_data_folder_is_the_projects_data_alone_and_the_value_cannot_change(user_data: Path) -> None:
    assert DataPaths().dirs() == DataPaths("").dirs() == DataPaths(None).dirs() == [PROJECT_DATA_DIR]
    assert DataPaths(PROJECT_DATA_DIR).dirs() == [PROJECT_DATA_DIR]  # listed once
    assert DataPaths(str(user_data)) == DataPaths(user_data)
    with pytest.raises(dataclasses.FrozenInstanceError):
        DataPaths(user_data).data_dir = None  # type: ignore[misc]
