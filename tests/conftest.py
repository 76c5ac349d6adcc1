"""Shared fixtures. Real MimicKit data comes from `$MIMICKIT_TEST_DATA` (CI: ../shared/data).

The unit/integration split: a test that starts a process (a subprocess, a server, a guarded loader's
child, Chromium) carries the mark `integration` or `browser`, usually for its whole module
(`pytestmark = pytest.mark.integration`); `make test-unit` runs the rest. The guard below keeps the
marks honest: a test without either mark that starts a process fails, naming the mark it needs. It
also sees processes started by the session and module fixtures a test is the first to ask for.
"""

from __future__ import annotations

import multiprocessing.process
import os
import platform
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from mimickit.util.paths import PROJECT_DATA_DIR

# warp (the Newton engine) asks platform.processor() when it builds its first model, which runs `uname -p`
# in a subprocess. Python caches the answer, so asking here, before any test, keeps that out of the guard.
platform.processor()
# matplotlib builds its font cache the first time it is imported, running `fc-list` when fontconfig is there.
# Building it here keeps a fresh machine's first plot test from tripping the guard.
import matplotlib.font_manager  # noqa: E402,F401

PROCESS_MARKS = ("integration", "browser")
_running: list[pytest.Item] = []  # the test being set up, run or torn down
_started = pytest.StashKey[list[str]]()


class ProcessInUnitTest(AssertionError):
    pass


def _may_start(what: str) -> None:
    item = _running[-1] if _running else None  # None: collection, where module imports may probe
    if item is None or any(item.get_closest_marker(m) for m in PROCESS_MARKS):
        return
    item.stash.setdefault(_started, []).append(what)
    raise ProcessInUnitTest(f"{item.nodeid} starts {what}: mark it integration (or browser)")


_popen_init = subprocess.Popen.__init__
_process_start = multiprocessing.process.BaseProcess.start


def _guarded_popen_init(self: subprocess.Popen, args: object, *rest: object, **kw: object) -> None:
    _may_start(f"the process {args!r}")
    _popen_init(self, args, *rest, **kw)


def _guarded_process_start(self: multiprocessing.process.BaseProcess) -> None:
    _may_start(f"a {type(self).__name__} running {getattr(self, '_target', None)!r}")
    _process_start(self)


subprocess.Popen.__init__ = _guarded_popen_init
multiprocessing.process.BaseProcess.start = _guarded_process_start


@pytest.hookimpl(wrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    _running.append(item)
    try:
        return (yield)
    finally:
        _running.pop()


@pytest.fixture(autouse=True)
def _no_process_in_unit_tests(request: pytest.FixtureRequest) -> Iterator[None]:
    """Fails the test even where the code under test caught the guard's exception."""
    yield
    started = request.node.stash.get(_started, [])
    if started:
        pytest.fail(f"a test without the integration or browser mark started {started[0]}", pytrace=False)


PROJECT_HUMANOID = PROJECT_DATA_DIR / "assets" / "humanoid" / "humanoid.xml"
DEMO_CLIP = PROJECT_DATA_DIR / "motions" / "humanoid_demo_squat.pkl"


def write_shifted_demo_clip(path: Path) -> Path:
    """Another clip for the humanoid: the demo squat starting at its deepest frame.

    The squat is symmetric in time, so played backwards it is the same clip: shifting by half a cycle
    is what makes every pose at a given time differ from the demo's."""
    import numpy as np

    from mimickit.anim.motion import LoopMode, Motion, load_motion, save_motion

    demo = load_motion(DEMO_CLIP)
    frames = np.roll(demo.frames, -(len(demo.frames) // 2), axis=0)
    assert np.abs(frames - demo.frames).max() > 0.1
    path.parent.mkdir(parents=True, exist_ok=True)
    save_motion(path, Motion(LoopMode.CLAMP, demo.fps, np.ascontiguousarray(frames)))
    return path


def test_data_dir() -> Path | None:
    value = os.environ.get("MIMICKIT_TEST_DATA")
    return Path(value).resolve() if value else None


@pytest.fixture(scope="session")
def test_data() -> Path:
    d = test_data_dir()
    if d is None:
        pytest.skip("MIMICKIT_TEST_DATA is not set: no MimicKit reference data to test against")
    if not d.is_dir():
        pytest.fail(f"MIMICKIT_TEST_DATA={d} is not a folder")
    return d


@pytest.fixture(scope="session")
def ref_humanoid_xml(test_data: Path) -> Path:
    return test_data / "assets" / "humanoid" / "humanoid.xml"
