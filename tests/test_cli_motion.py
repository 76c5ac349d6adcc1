"""`mimickit motion ...` as a user runs it: a real subprocess, exit codes, one-line errors."""

import json
import math
import os
import pickle
import subprocess
import sys

import numpy as np
import pytest

from tests.conftest import DEMO_CLIP, PROJECT_HUMANOID
from tests.hostile.pkl_cases import clip, f32_storage, tensor

pytestmark = pytest.mark.integration


def mimickit(*args, cwd=None):
    return subprocess.run(
        [sys.executable, "-m", "mimickit.cli", *map(str, args)], capture_output=True, text=True, cwd=cwd
    )


def test_info_json_of_demo_clip():
    r = mimickit("motion", "info", DEMO_CLIP, "--char", PROJECT_HUMANOID, "--json")
    assert r.returncode == 0, r.stderr
    (info,) = json.loads(r.stdout)
    assert info["path"] == str(DEMO_CLIP)
    assert (info["fps"], info["loop_mode"], info["num_frames"], info["frame_dim"]) == (30, "wrap", 91, 34)
    assert info["duration"] == pytest.approx(3.0)
    assert info["limit_violations"] == []


def test_info_text_reports_nan_and_limits(test_data):
    walk = test_data / "motions/humanoid/humanoid_walk.pkl"
    r = mimickit("motion", "info", walk, "--char", PROJECT_HUMANOID)
    assert r.returncode == 0, r.stderr
    assert "NaN columns [9, 10, 11]" in r.stdout
    assert "left_knee" in r.stdout  # the official walk bends the left knee past its limit by ~0.013 rad


def test_info_json_many(test_data):
    paths = sorted((test_data / "motions/go2").glob("*.pkl"))
    r = mimickit("motion", "info", "--json", *paths)
    infos = json.loads(r.stdout)
    assert [i["path"] for i in infos] == [str(p) for p in paths]
    assert {i["frame_dim"] for i in infos} == {18}


def test_wrong_width_for_char_is_one_line(test_data):
    r = mimickit("motion", "info", test_data / "motions/go2/go2_run.pkl", "--char", PROJECT_HUMANOID)
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "18 columns" in r.stderr and "Traceback" not in r.stderr


def test_validate_lists_problems(tmp_path):
    bad = tmp_path / "bad.pkl"
    bad.write_bytes(pickle.dumps({"loop_mode": 0, "fps": 30}))
    text = tmp_path / "text.pkl"
    text.write_text("not a pickle")
    r = mimickit("motion", "validate", DEMO_CLIP, bad, text)
    assert r.returncode == 1
    assert f"{DEMO_CLIP}: ok" in r.stdout
    assert "bad.pkl: missing key(s) frames" in r.stderr and "text.pkl: not a MimicKit clip" in r.stderr
    assert "Traceback" not in r.stderr


def test_missing_file_and_help():
    r = mimickit("motion", "info", "nope.pkl")
    assert r.returncode == 2 and "motion file not found: nope.pkl" in r.stderr
    for args in (["--help"], ["motion", "--help"], ["motion", "info", "--help"], ["motion", "convert", "--help"]):
        assert mimickit(*args).returncode == 0


def _clip(path, frames, fps=30):
    path.write_bytes(pickle.dumps({"loop_mode": 0, "fps": fps, "frames": frames}))
    return path


def test_validate_flags_non_finite_none_absurd_fps_and_complex(tmp_path):
    row = [0.1 * i for i in range(34)]
    nan_col = [r[:9] + [math.nan] + r[10:] for r in [row] * 4]
    cases = {
        _clip(tmp_path / "all_nan.pkl", [[math.nan] * 34] * 4): "are NaN in every frame",
        _clip(tmp_path / "nan_col.pkl", nan_col): "columns [9] are NaN in every frame",
        _clip(tmp_path / "one_inf.pkl", [row, row[:5] + [math.inf] + row[6:]]): "1 non-finite values",
        _clip(tmp_path / "all_none.pkl", [[None] * 34] * 4): "is None, not a number; columns [0, 1,",
        _clip(tmp_path / "tiny_fps.pkl", [row] * 4, fps=1e-300): "fps must be between 0.001 and 10000",
        _clip(tmp_path / "complex.pkl", [[complex(1, 1)] * 34] * 4): "complex numbers are not allowed",
    }
    r = mimickit("motion", "validate", *cases)
    assert r.returncode == 1, r.stderr
    assert "Traceback" not in r.stderr and r.stdout == ""
    lines = r.stderr.strip().splitlines()
    for path, needle in cases.items():
        assert [line for line in lines if line.startswith(f"{path}:") and needle in line], (path, needle, lines)
    assert lines[-1] == "6 of 6 file(s) invalid"


def test_info_on_hostile_files_is_one_error_line(tmp_path):
    hostile = {
        "stride.pkl": clip(tensor(f32_storage(np.array([30.0])), 0, (2,), (2**40,))),  # segfaulted before
        "huge_int.pkl": pickle.dumps({"loop_mode": 0, "fps": 30, "frames": [[10**400] + [0.0] * 33] * 2}),
        "memo.pkl": b"\x80\x03]r\x00\x00\x00\x80.",
        "empty.pkl": b"",
        "text.pkl": b"hello\n",
    }
    for name, data in hostile.items():
        (tmp_path / name).write_bytes(data)
        r = mimickit("motion", "info", tmp_path / name)
        assert r.returncode == 2, (name, r.returncode, r.stderr[-500:])
        assert r.stderr.startswith(f"error: {tmp_path / name}") and r.stderr.count("\n") == 1, (name, r.stderr)


def test_frame_limit_through_the_environment(tmp_path):
    clip = _clip(tmp_path / "c.pkl", [[0.5] * 34] * 50)
    env = {**os.environ, "MIMICKIT_MAX_FRAMES": "10"}
    r = subprocess.run(
        [sys.executable, "-m", "mimickit.cli", "motion", "info", str(clip)], capture_output=True, text=True, env=env
    )
    assert r.returncode == 2
    assert r.stderr == f"error: {clip}: 50 frames is over the limit of 10 (set MIMICKIT_MAX_FRAMES to allow more)\n"
    env["MIMICKIT_MAX_FRAMES"] = "ten"
    r = subprocess.run(
        [sys.executable, "-m", "mimickit.cli", "motion", "info", str(clip)], capture_output=True, text=True, env=env
    )
    assert r.returncode == 2 and r.stderr == "error: MIMICKIT_MAX_FRAMES='ten' is not a whole number\n"
