"""`mimickit motion convert` for GMR robot motions and AMASS files, as a user runs it (subprocess), and
the GMR converter itself. The SMPL pose conversion is judged in test_smpl_convert.py."""

from __future__ import annotations

import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from mimickit.anim.mjcf_char_model import load_char_model
from mimickit.anim.motion import LoopMode, load_motion
from mimickit.anim.motion_lib import MotionLib
from mimickit.tools.gmr_convert import gmr_to_motion, load_gmr
from mimickit.tools.motion_convert import ConvertOptions, convert_motion, detect_format
from mimickit.tools.motion_report import check_frame_dim
from mimickit.util import torch_util as tu
from mimickit.util.errors import MimicKitError
from tests.tools.test_smpl_convert import random_amass

pytestmark = pytest.mark.integration

rng = np.random.default_rng(3)


def mimickit(*args: object) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mimickit.cli", *map(str, args)], capture_output=True, text=True)


def gmr_motion(T: int = 61, dofs: int = 29, fps: float = 30.0) -> dict:
    """What GMR's scripts save: root_rot is MuJoCo's qpos[3:7] reordered to x y z w."""
    t = np.arange(T) / fps
    wxyz = np.stack([np.cos(0.3 * t), 0.1 * np.sin(t), 0.05 * np.ones(T), np.sin(0.3 * t)], axis=1)
    wxyz /= np.linalg.norm(wxyz, axis=1, keepdims=True)
    return {
        "fps": fps,
        "root_pos": np.stack([0.8 * t, 0.0 * t, 0.78 + 0.02 * np.sin(4 * t)], axis=1),
        "root_rot": wxyz[:, [1, 2, 3, 0]],
        "dof_pos": 0.3 * np.sin(t[:, None] * np.linspace(1, 3, dofs)[None]),
        "local_body_pos": None,
        "link_body_list": None,
    }


@pytest.fixture(scope="module")
def g1_xml(test_data: Path) -> Path:
    return test_data / "assets" / "g1" / "g1.xml"


def test_gmr_pickle_converts_and_loads_on_g1(tmp_path: Path, g1_xml: Path) -> None:
    data = gmr_motion()
    src = tmp_path / "walk_gmr.pkl"
    src.write_bytes(pickle.dumps(data))
    out = tmp_path / "g1_walk.pkl"
    r = mimickit("motion", "convert", src, out, "--char", g1_xml)
    assert r.returncode == 0, r.stderr
    assert "61 frames at 30 fps" in r.stdout and "[gmr]" in r.stdout
    motion = load_motion(out)
    char = load_char_model(g1_xml)
    check_frame_dim(motion, char, out)
    assert (motion.fps, motion.frame_dim, motion.loop_mode) == (30, 35, LoopMode.WRAP)
    np.testing.assert_allclose(motion.frames[:, :3], data["root_pos"], atol=1e-6)
    np.testing.assert_allclose(motion.frames[:, 6:], data["dof_pos"], atol=1e-6)
    q = tu.exp_map_to_quat(torch.from_numpy(motion.frames[:, 3:6]).double())
    expected = torch.from_numpy(data["root_rot"])
    assert tu.quat_diff_angle(q, expected).max() < 1e-5
    lib = MotionLib(str(out), char, "cpu")
    assert lib.get_total_length() == pytest.approx(2.0)


def test_gmr_wxyz_order_and_npz(tmp_path: Path) -> None:
    data = gmr_motion(dofs=12)
    xyzw = gmr_to_motion(data)
    data_wxyz = dict(data, root_rot=data["root_rot"][:, [3, 0, 1, 2]])
    np.savez(tmp_path / "m.npz", **{k: v for k, v in data_wxyz.items() if v is not None})
    assert detect_format(tmp_path / "m.npz") == "gmr"
    wxyz = gmr_to_motion(load_gmr(tmp_path / "m.npz"), root_rot_order="wxyz")
    np.testing.assert_allclose(wxyz.frames, xyzw.frames, atol=1e-6)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: d.pop("dof_pos"), "missing key 'dof_pos'"),
        (lambda d: d.update(root_rot=d["root_rot"][:, :3]), "key 'root_rot' has shape (61, 3)"),
        (lambda d: d.update(root_pos=d["root_pos"][:10]), "disagree on the number of frames ('root_pos' 10,"),
        (lambda d: d.update(fps="fast"), "key 'fps'"),
        (lambda d: d.update(dof_pos=d["dof_pos"][:, :12]), "key 'dof_pos' has 12 DoFs per frame"),
    ],
)
def test_bad_gmr_file_is_one_line_naming_file_and_key(tmp_path: Path, g1_xml: Path, change, message: str) -> None:
    data = gmr_motion()
    change(data)
    src = tmp_path / "bad.pkl"
    src.write_bytes(pickle.dumps(data))
    r = mimickit("motion", "convert", src, tmp_path / "out.pkl", "--char", g1_xml)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and str(src) in lines[0] and message in lines[0], lines
    assert not (tmp_path / "out.pkl").exists()


def test_gmr_pickle_with_code_is_refused(tmp_path: Path) -> None:
    class Evil:
        def __reduce__(self):
            return (print, ("pwned",))

    src = tmp_path / "evil.pkl"
    src.write_bytes(pickle.dumps({"fps": 30, "root_pos": Evil()}))
    with pytest.raises(MimicKitError, match="not a GMR motion pickle"):
        load_gmr(src)


def test_amass_120_to_30_fps_through_the_cli(tmp_path: Path, test_data: Path) -> None:
    data = random_amass(T=241, width=156, fps=120.0)  # 2.0 s
    src = tmp_path / "take_poses.npz"
    np.savez(src, **data)
    out = tmp_path / "smpl_take.pkl"
    r = mimickit("motion", "convert", src, out, "--fps", 30, "--data_dir", test_data)
    assert r.returncode == 0, r.stderr
    assert "61 frames at 30 fps (2.000 s)" in r.stdout and "resampled from 120 fps" in r.stdout
    motion = load_motion(out)
    assert (motion.num_frames, motion.fps, motion.frame_dim) == (61, 30, 75)
    assert motion.duration == pytest.approx(240 / 120.0)
    # Every 4th input frame is an output frame: the same pose as converting at 120 fps.
    full = convert_motion(src, ConvertOptions(char=str(test_data / "assets/smpl/smpl.xml"))).motion
    assert full.num_frames == 241
    np.testing.assert_allclose(motion.frames, full.frames[::4], atol=2e-5)


def test_amass_without_the_smpl_character_says_how_to_get_it(tmp_path: Path) -> None:
    src = tmp_path / "a.npz"
    np.savez(src, **random_amass(T=10, width=72))
    r = mimickit("motion", "convert", src, tmp_path / "o.pkl")
    assert r.returncode == 2
    assert "smpl.xml" in r.stderr and "--char" in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_frame_range_and_loop(tmp_path: Path, test_data: Path) -> None:
    src = tmp_path / "a.npz"
    np.savez(src, **random_amass(T=50, width=72))
    opts = ConvertOptions(
        char=str(test_data / "assets/smpl/smpl.xml"), start_frame=10, end_frame=30, loop="clamp", z_correction="none"
    )
    m = convert_motion(src, opts).motion
    assert (m.num_frames, m.loop_mode) == (20, LoopMode.CLAMP)
    with pytest.raises(MimicKitError, match=r"frame range \[40, 80\)"):
        convert_motion(src, ConvertOptions(char=opts.char, start_frame=40, end_frame=80))


def test_deepmimic_text_still_converts_and_resamples(tmp_path: Path, test_data: Path) -> None:
    src = test_data / "deepmimic_motions" / "humanoid3d_walk.txt"
    r = mimickit("motion", "convert", src, tmp_path / "walk.pkl")
    assert r.returncode == 0, r.stderr
    assert "[deepmimic]" in r.stdout
    base = load_motion(tmp_path / "walk.pkl")
    r = mimickit("motion", "convert", src, tmp_path / "walk30.pkl", "--fps", 30)
    assert r.returncode == 0, r.stderr
    m = load_motion(tmp_path / "walk30.pkl")
    assert m.fps == 30 and abs(m.duration - base.duration) <= 0.5 / 30 + 1e-6
    assert m.loop_mode == base.loop_mode
