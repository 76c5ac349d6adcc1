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

from mimickit.anim.motion import LoopMode, Motion, load_motion, save_motion
from mimickit.util.errors import MimicKitError


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
