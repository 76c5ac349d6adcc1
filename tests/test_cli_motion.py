"""`mimickit motion ...` as a user runs it: a real subprocess, exit codes, one-line errors."""

import json
import pickle
import subprocess
import sys

import pytest

from tests.conftest import DEMO_CLIP, PROJECT_HUMANOID


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
