"""Reading and writing MimicKit .pkl clips, safely."""

import os
import pickle
import re
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from mimickit.anim.motion import (
    LoopMode,
    Motion,
    load_motion,
    load_motion_guarded,
    motion_from_bytes_guarded,
    motion_from_dict,
    save_motion,
)
from mimickit.util.errors import MimicKitError
from mimickit.util.limits import ClipLimits

pytestmark = pytest.mark.integration


def _facts_table(test_data: Path) -> list[tuple[str, float, int, int, int, float]]:
    """Rows of the per-clip facts table in SOURCES.md: path, fps, loop, frames, cols, duration."""
    rows = []
    for line in (test_data / "SOURCES.md").read_text().splitlines():
        m = re.match(r"\| (motions/\S+\.pkl) \| ([\d.]+) \| (\d) \| (\d+)x(\d+) \| ([\d.]+) \|", line)
        if m:
            rows.append((m[1], float(m[2]), int(m[3]), int(m[4]), int(m[5]), float(m[6])))
    return rows


def test_every_clip_loads(test_data):
    paths = sorted((test_data / "motions").rglob("*.pkl"))
    assert len(paths) > 200
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for p in paths:
            m = load_motion(p)
            assert m.frame_dim in (18, 28, 34, 35, 75), p
            assert np.isfinite(m.frames).all()


def test_clips_agree_with_sources_facts(test_data):
    rows = _facts_table(test_data)
    assert len(rows) > 60
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for path, fps, loop, frames, cols, duration in rows:
            m = load_motion(test_data / path)
            assert (m.fps, int(m.loop_mode), m.num_frames, m.frame_dim) == (fps, loop, frames, cols), path
            assert m.duration == pytest.approx(duration, abs=1e-3), path


def test_nan_columns_become_zero_with_warning(test_data):
    with pytest.warns(UserWarning, match=r"columns \[9, 10, 11\]"):
        m = load_motion(test_data / "motions/humanoid/humanoid_walk.pkl")
    assert m.nan_columns == (9, 10, 11)
    assert (m.frames[:, 9:12] == 0).all()


def test_torch_scalar_fps_decoded_without_torch_code(test_data):
    m = load_motion(test_data / "motions/humanoid/humanoid_double_kong.pkl")
    # The file's own values (read once with torch and pickle.load: fps tensor(30.), 156 frames, loop_mode 0).
    assert m.fps == 30.0 and m.num_frames == 156 and m.loop_mode == LoopMode.CLAMP


def test_round_trip_is_identical_and_plain(tmp_path, test_data):
    src = test_data / "motions/humanoid/humanoid_spinkick.pkl"
    a = load_motion(src)
    out = tmp_path / "a.pkl"
    save_motion(out, a)
    b = load_motion(out)
    assert (a.fps, a.loop_mode) == (b.fps, b.loop_mode)
    np.testing.assert_array_equal(a.frames, b.frames)
    save_motion(tmp_path / "b.pkl", b)
    assert out.read_bytes() == (tmp_path / "b.pkl").read_bytes()
    # The saved file is plain python data: it loads with pickle alone, no numpy or torch imported.
    code = (
        "import pickle, sys; d = pickle.load(open(sys.argv[1], 'rb'));"
        "assert set(d) == {'loop_mode', 'fps', 'frames'} and type(d['frames'][0][0]) is float;"
        "assert 'numpy' not in sys.modules and 'torch' not in sys.modules; print(len(d['frames']))"
    )
    r = subprocess.run([sys.executable, "-c", code, str(out)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == str(a.num_frames)


class _Evil:
    def __reduce__(self):
        return (os.system, ("touch pwned_by_pickle",))


def test_malicious_pickle_is_refused_and_nothing_runs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    p = tmp_path / "evil.pkl"
    p.write_bytes(pickle.dumps({"loop_mode": 0, "fps": 30, "frames": _Evil()}))
    with pytest.raises(MimicKitError, match="refused to load global"):
        load_motion(p)
    assert not (tmp_path / "pwned_by_pickle").exists()


def test_truncated_and_text_files(tmp_path, test_data):
    data = (test_data / "motions/humanoid/humanoid_run.pkl").read_bytes()
    trunc = tmp_path / "trunc.pkl"
    trunc.write_bytes(data[: len(data) // 2])
    with pytest.raises(MimicKitError, match="trunc.pkl"):
        load_motion(trunc)
    text = tmp_path / "notes.pkl"
    text.write_text("this is a text file, not a pickle\n")
    with pytest.raises(MimicKitError, match="notes.pkl: not a MimicKit clip"):
        load_motion(text)


@pytest.mark.parametrize(
    "obj, needle",
    [
        ([1, 2, 3], "expected a dict"),
        ({"fps": 30, "frames": [[0.0] * 34]}, "missing key"),
        ({"loop_mode": 3, "fps": 30, "frames": [[0.0] * 34]}, "loop_mode"),
        ({"loop_mode": 0, "fps": -1, "frames": [[0.0] * 34]}, "fps"),
        ({"loop_mode": 0, "fps": 30, "frames": [[0.0] * 34, [0.0] * 33]}, "frames"),
    ],
)
def test_bad_contents(tmp_path, obj, needle):
    p = tmp_path / "bad.pkl"
    p.write_bytes(pickle.dumps(obj))
    with pytest.raises(MimicKitError, match=needle):
        load_motion(p)


def test_save_writes_plain_numbers(tmp_path):
    m = Motion(LoopMode.WRAP, 30.0, np.zeros((3, 34), dtype=np.float32))
    save_motion(tmp_path / "z.pkl", m)
    d = pickle.loads((tmp_path / "z.pkl").read_bytes())
    assert d["fps"] == 30 and type(d["fps"]) is int and d["loop_mode"] == 1


# --- limits, and the guarded loaders -------------------------------------------------------------


def _clip_bytes(num_frames: int, width: int = 34, fps: float = 30) -> bytes:
    return pickle.dumps({"loop_mode": 0, "fps": fps, "frames": [[0.5 + i] * width for i in range(num_frames)]})


def test_frame_limit_from_argument_and_environment(tmp_path, monkeypatch):
    p = tmp_path / "long.pkl"
    p.write_bytes(_clip_bytes(200))
    with pytest.raises(MimicKitError, match=r"long.pkl: 200 frames is over the limit of 100 \(set MIMICKIT_MAX_FRAMES"):
        load_motion(p, limits=ClipLimits(max_frames=100))
    monkeypatch.setenv("MIMICKIT_MAX_FRAMES", "150")
    with pytest.raises(MimicKitError, match="over the limit of 150"):
        load_motion(p)
    monkeypatch.setenv("MIMICKIT_MAX_FRAMES", "200")
    assert load_motion(p).num_frames == 200


def test_file_size_limit_is_checked_before_reading(tmp_path, monkeypatch):
    p = tmp_path / "big.pkl"
    p.write_bytes(_clip_bytes(200))  # 62 kB
    monkeypatch.setenv("MIMICKIT_MAX_CLIP_MB", "0.01")
    with pytest.raises(MimicKitError, match=r"big.pkl: \d+ bytes is over the 0.01 MB limit .* MIMICKIT_MAX_CLIP_MB"):
        load_motion(p)
    monkeypatch.setenv("MIMICKIT_MAX_CLIP_MB", "bogus")
    with pytest.raises(MimicKitError, match="MIMICKIT_MAX_CLIP_MB='bogus' is not a number"):
        load_motion(p)


def test_fps_bounds_are_limits(tmp_path):
    p = tmp_path / "slow.pkl"
    p.write_bytes(_clip_bytes(3, fps=0.0005))
    with pytest.raises(MimicKitError, match="fps must be between 0.001 and 10000"):
        load_motion(p)
    assert load_motion(p, limits=ClipLimits(min_fps=1e-4)).fps == 0.0005


def test_motion_from_dict_checks_before_converting():
    shared = [[0.5] * 100] * 100
    bomb = {"loop_mode": 0, "fps": 30, "frames": [shared] * 100}  # 10**6 rows of 100 lists deep, if expanded
    with pytest.raises(MimicKitError, match=r"frames\[0\]\[0\] is a list; frames must be 2-D"):
        motion_from_dict(bomb)
    m = motion_from_dict({"loop_mode": 1, "fps": np.float32(50), "frames": np.ones((4, 34), np.float64)})
    assert (m.fps, m.num_frames, m.frames.dtype) == (50.0, 4, np.float32)


def test_guarded_loader_matches_in_process(test_data):
    for rel in ("humanoid/humanoid_double_kong.pkl", "go2/go2_run.pkl", "humanoid/long/humanoid_long_walk0.pkl"):
        p = test_data / "motions" / rel
        a, b = load_motion(p), load_motion_guarded(p)
        assert (a.fps, a.loop_mode, a.nan_columns) == (b.fps, b.loop_mode, b.nan_columns)
        np.testing.assert_array_equal(a.frames, b.frames)
        assert b.frames.flags.writeable and b.frames.dtype == np.float32


def test_guarded_loader_warns_and_sanitizes_in_the_caller(test_data):
    walk = test_data / "motions/humanoid/humanoid_walk.pkl"
    with pytest.warns(UserWarning, match=r"columns \[9, 10, 11\]"):
        m = load_motion_guarded(walk)
    assert (m.frames[:, 9:12] == 0).all()
    raw = load_motion_guarded(walk, sanitize_nan=False)
    assert np.isnan(raw.frames[:, 9:12]).all()


def test_guarded_bytes_loader_errors_are_the_loaders(tmp_path):
    m = motion_from_bytes_guarded(_clip_bytes(5), source="upload.pkl")
    assert m.num_frames == 5
    refused = r"^upload.pkl: not a MimicKit clip \(refused to load global '(os|posix).system'\)$"
    with pytest.raises(MimicKitError, match=refused):
        motion_from_bytes_guarded(pickle.dumps({"frames": _Evil()}), source="upload.pkl")
    with pytest.raises(MimicKitError, match="^motion file not found"):
        load_motion_guarded(tmp_path / "missing.pkl")


LIST_BOMB = b"\x80\x03](" + b"]" * 16_000_000 + b"e."  # 16 MB: a gigabyte of empty lists


def test_guarded_loader_memory_and_time_budgets(tmp_path):
    p = tmp_path / "bomb.pkl"
    p.write_bytes(LIST_BOMB)
    with pytest.raises(MimicKitError, match="would need more than 1024 MB"):  # the pre-scan refuses it
        load_motion_guarded(p)
    # With the pre-scan's budget lifted, the child's address-space bound and its time budget stop it.
    no_scan = ClipLimits(max_parse_mb=1e6, parse_memory_mb=300)
    with pytest.raises(MimicKitError, match=r"bomb.pkl needs more than 300 MB to parse$"):
        load_motion_guarded(p, limits=no_scan)
    quick = ClipLimits(max_parse_mb=1e6, parse_timeout_s=0.2)
    with pytest.raises(MimicKitError, match=r"bomb.pkl took longer than 0.2 s to parse$"):
        load_motion_guarded(p, limits=quick)


def test_in_process_memory_error_is_one_line(tmp_path):
    p = tmp_path / "bomb.pkl"
    p.write_bytes(LIST_BOMB)
    code = (
        "import resource, sys\n"
        "from mimickit.anim.motion import load_motion\n"
        "from mimickit.util.limits import ClipLimits\n"
        "resource.setrlimit(resource.RLIMIT_AS, (1500 * 2**20, resource.RLIM_INFINITY))\n"
        "try:\n load_motion(sys.argv[1], limits=ClipLimits(max_parse_mb=1e6))\n"
        "except Exception as e:\n print(type(e).__name__, e)\n"
    )
    r = subprocess.run([sys.executable, "-c", code, str(p)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip() == f"MimicKitError {p}: ran out of memory parsing the clip"
