"""Hostile `.pkl` clips (issue 17): every crafted case gets one clear error line or loads exactly.

The cases (tests/hostile/pkl_cases.py) cover what crashed, stalled or leaked before: tensor views
with out-of-range or negative strides and offsets, a [64, 34] view over 34 floats, shared nested
lists, a 2,000,000-frame clip, 10**400, giant memo indices and byte lengths, non-finite and None
values, absurd fps, complex and object data, code-running globals, truncated and foreign files.
The ones that crashed the interpreter before also run through `mimickit motion info` in a
subprocess, so a segfault fails the test instead of the test run.
"""

from __future__ import annotations

import re
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from mimickit.anim.motion import load_motion
from mimickit.tools.motion_report import validate_motion
from mimickit.util.errors import MimicKitError
from tests.conftest import DEMO_CLIP
from tests.hostile.pkl_cases import Case, all_cases, frames_from_file

pytestmark = pytest.mark.integration

CASES = all_cases()
REAL_CLIPS = [
    "humanoid/humanoid_spinkick.pkl",
    "humanoid/humanoid_double_kong.pkl",  # fps is a legacy torch tensor
    "humanoid/long/humanoid_long_walk0.pkl",  # the largest official clip
    "go2/go2_run.pkl",
    "g1/g1_cartwheel.pkl",
    "smpl/smpl_backflip.pkl",
    "hightorque_pi_plus/pi_plus_walk.pkl",
]


@pytest.fixture(scope="module")
def case_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("pkl_cases")
    for case in CASES:
        (d / f"{case.id}.pkl").write_bytes(case.data)
    return d


def _one_line(msg: str, path: Path) -> None:
    assert "\n" not in msg and len(msg) < 600, msg
    assert str(path) in msg, msg
    assert "Traceback" not in msg


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_crafted_clip(case: Case, case_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(case_dir)  # a global that ran a command would leave its file here
    path = case_dir / f"{case.id}.pkl"
    if case.outcome == "error":
        with pytest.raises(MimicKitError) as err:
            load_motion(path, limits=case.limits)
        msg = str(err.value)
        _one_line(msg, path)
        assert re.search(case.match, msg), msg
        if case.limits is None:
            assert validate_motion(path) == ([msg], [])
    elif case.outcome == "invalid":
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            load_motion(path)
        problems, _ = validate_motion(path)
        assert problems, "validate passed a clip it must flag"
        for line in problems:
            _one_line(line, path)
        assert any(re.search(case.match, line) for line in problems), problems
    else:
        m = load_motion(path, limits=case.limits)
        if case.frames is not None:
            np.testing.assert_array_equal(m.frames, case.frames)
        assert frames_from_file(m.frames, case.data), "frame values that are not in the file"
        if case.limits is None:
            assert validate_motion(path) == ([], [])
    assert not (case_dir / "pwned_by_pickle").exists()


@pytest.mark.parametrize("rel", REAL_CLIPS, ids=[f"ok-real-{Path(r).stem}" for r in REAL_CLIPS])
def test_real_clip(rel: str, test_data: Path) -> None:
    path = test_data / "motions" / rel
    m = load_motion(path)
    assert m.num_frames >= 2 and np.isfinite(m.frames).all()
    assert frames_from_file(m.frames, path.read_bytes())
    assert validate_motion(path) == ([], [])


@pytest.mark.parametrize("path", [pytest.param(DEMO_CLIP, id="ok-real-project-demo-squat")])
def test_project_demo_clip(path: Path) -> None:
    m = load_motion(path)
    assert (m.num_frames, m.frame_dim, m.fps) == (91, 34, 30.0)
    assert frames_from_file(m.frames, path.read_bytes())
    assert validate_motion(path) == ([], [])


WALK = pytest.param("motions/humanoid/humanoid_walk.pkl", id="err-validate-real-walk-nan-neck")


@pytest.mark.parametrize("rel", [WALK])
def test_official_walk_nan_neck_is_flagged(rel: str, test_data: Path) -> None:
    walk = test_data / rel
    problems, _ = validate_motion(walk)
    assert problems == [f"{walk}: columns [9, 10, 11] are NaN in every frame (read as 0 when training)"]


def _cli(*args: object, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "mimickit.cli", *map(str, args)], capture_output=True, text=True, cwd=cwd, timeout=120
    )


CRASHERS = [c for c in CASES if c.crashed_before]


@pytest.mark.parametrize("case", CRASHERS, ids=[f"err-cli-{c.id}" for c in CRASHERS])
def test_cli_info_on_former_crasher(case: Case, case_dir: Path) -> None:
    """`mimickit motion info` in its own process: a segfault shows as a negative return code."""
    path = case_dir / f"{case.id}.pkl"
    r = _cli("motion", "info", path, cwd=case_dir)
    assert r.returncode == 2, (r.returncode, r.stderr[-2000:])
    assert r.stdout == ""
    assert r.stderr.count("\n") == 1 and r.stderr.startswith("error: ") and "Traceback" not in r.stderr
    assert re.search(case.match, r.stderr), r.stderr


def test_cli_validate_every_bad_case_in_one_process(case_dir: Path) -> None:
    """Every error and invalid case through `mimickit motion validate`: exit 1, each file named."""
    bad = [c for c in CASES if c.outcome != "ok" and c.limits is None]
    r = _cli("motion", "validate", *(case_dir / f"{c.id}.pkl" for c in bad), cwd=case_dir)
    assert r.returncode == 1, (r.returncode, r.stderr[-2000:])
    assert "Traceback" not in r.stderr
    for c in bad:
        assert f"{case_dir / c.id}.pkl" in r.stderr, c.id
    assert r.stderr.strip().splitlines()[-1] == f"{len(bad)} of {len(bad)} file(s) invalid"
    assert not (case_dir / "pwned_by_pickle").exists()


def test_cli_validate_ok_cases_pass(case_dir: Path) -> None:
    good = [c for c in CASES if c.outcome == "ok" and c.limits is None]
    r = _cli("motion", "validate", *(case_dir / f"{c.id}.pkl" for c in good), cwd=case_dir)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.count(": ok\n") == len(good)
