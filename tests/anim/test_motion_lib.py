"""MotionLib: sampling by weight, clamp and wrap, interpolation and velocities."""

import math

import numpy as np
import pytest
import torch

from mimickit.anim.mjcf_char_model import load_char_model
from mimickit.anim.motion import LoopMode, Motion, save_motion
from mimickit.anim.motion_lib import MotionLib
from mimickit.util import torch_util as tu
from mimickit.util.errors import MimicKitError
from tests.conftest import DEMO_CLIP, PROJECT_HUMANOID


@pytest.fixture(scope="module")
def char():
    return load_char_model(PROJECT_HUMANOID)


def _walking_clip(loop: LoopMode, n: int = 11, fps: float = 10.0) -> Motion:
    """Root walks +x at 1 m/s while the right knee bends linearly 0 → 1 rad; yaw turns 0 → 0.5 rad."""
    frames = np.zeros((n, 34), dtype=np.float32)
    t = np.arange(n) / fps
    frames[:, 0] = t
    frames[:, 2] = 0.9
    frames[:, 5] = 0.5 * t / t[-1]
    frames[:, 6 + 17] = t / t[-1]
    return Motion(loop, fps, frames)


def test_interpolation_and_velocities(char):
    lib = MotionLib([_walking_clip(LoopMode.CLAMP)], char)
    f = lib.calc_motion_frame(torch.tensor([0]), torch.tensor([0.25]))
    torch.testing.assert_close(f.root_pos[0], torch.tensor([0.25, 0.0, 0.9]))
    knee = lib.joint_rot_to_dof(f.joint_rot)[0, 17]
    assert knee.item() == pytest.approx(0.25, abs=1e-5)  # slerp of a single-axis rotation is linear
    yaw = tu.calc_heading(f.root_rot)[0]
    assert yaw.item() == pytest.approx(0.125, abs=1e-5)  # 0.5 rad over the 1 s clip, at 0.25 s
    # velocities come from frame i0 (finite differences), not interpolated
    torch.testing.assert_close(f.root_vel[0], torch.tensor([1.0, 0.0, 0.0]), atol=1e-5, rtol=0)
    assert f.dof_vel[0, 17].item() == pytest.approx(1.0, abs=1e-4)
    assert f.root_ang_vel[0, 2].item() == pytest.approx(0.5, abs=1e-4)


def test_clamp_freezes_after_end_and_before_start(char):
    lib = MotionLib([_walking_clip(LoopMode.CLAMP)], char)
    ids = torch.tensor([0, 0])
    f = lib.calc_motion_frame(ids, torch.tensor([5.0, -1.0]))
    torch.testing.assert_close(f.root_pos[0], torch.tensor([1.0, 0.0, 0.9]))
    torch.testing.assert_close(f.root_pos[1], torch.tensor([0.0, 0.0, 0.9]))
    # last frame's velocity repeats its predecessor's
    assert f.root_vel[0, 0].item() == pytest.approx(1.0, abs=1e-5)


def test_wrap_shifts_root_each_cycle(char):
    lib = MotionLib([_walking_clip(LoopMode.WRAP)], char)
    length = lib.get_motion_length(torch.tensor([0])).item()
    assert length == pytest.approx(1.0)
    d = 0.3
    a = lib.calc_motion_frame(torch.tensor([0]), torch.tensor([d]))
    b = lib.calc_motion_frame(torch.tensor([0]), torch.tensor([2 * length + d]))
    torch.testing.assert_close(b.root_pos, a.root_pos + torch.tensor([[2.0, 0.0, 0.0]]), atol=1e-5, rtol=0)
    torch.testing.assert_close(tu.quat_pos(b.joint_rot), tu.quat_pos(a.joint_rot), atol=1e-5, rtol=0)
    c = lib.calc_motion_frame(torch.tensor([0]), torch.tensor([d - length]))
    torch.testing.assert_close(c.root_pos, a.root_pos - torch.tensor([[1.0, 0.0, 0.0]]), atol=1e-5, rtol=0)
    assert lib.calc_motion_phase(torch.tensor([0]), torch.tensor([2.3])).item() == pytest.approx(0.3, abs=1e-5)


def test_dataset_weights_sample_in_proportion(char, tmp_path):
    for i in range(3):
        save_motion(tmp_path / f"c{i}.pkl", _walking_clip(LoopMode.WRAP, n=5 + i))
    ds = tmp_path / "dataset.yaml"
    ds.write_text(
        "motions:\n"
        f"  - {{file: {tmp_path / 'c0.pkl'}, weight: 1}}\n"
        f"  - {{file: {tmp_path / 'c1.pkl'}, weight: 3}}\n"
        f"  - {{file: {tmp_path / 'c2.pkl'}, weight: 6}}\n"
    )
    lib = MotionLib(ds, char)
    assert lib.num_motions() == 3
    torch.manual_seed(0)
    counts = torch.bincount(lib.sample_motions(20000), minlength=3).float() / 20000
    torch.testing.assert_close(counts, torch.tensor([0.1, 0.3, 0.6]), atol=0.015, rtol=0)
    times = lib.sample_time(torch.tensor([2] * 1000))
    assert times.min() >= 0 and times.max() <= lib.get_motion_length(torch.tensor([2])).item()


def test_dataset_errors_name_file_and_entry(char, tmp_path):
    ds = tmp_path / "d.yaml"
    ds.write_text("motions:\n  - {file: nowhere.pkl, weight: 1}\n")
    with pytest.raises(MimicKitError, match=r"d.yaml: motions\[0\].file not found"):
        MotionLib(ds, char)
    ds.write_text("motions:\n  - {file: nowhere.pkl, wieght: 1}\n")
    with pytest.raises(MimicKitError, match="unknown key"):
        MotionLib(ds, char)


def test_wrong_frame_width_for_character(char, tmp_path):
    m = Motion(LoopMode.WRAP, 30, np.zeros((4, 18), dtype=np.float32))
    save_motion(tmp_path / "go2like.pkl", m)
    with pytest.raises(MimicKitError, match="18 columns"):
        MotionLib(tmp_path / "go2like.pkl", char)


def test_official_dataset_yaml_loads(char, test_data, monkeypatch):
    from mimickit.util.paths import DataPaths

    go2 = load_char_model(test_data / "assets/go2/go2.xml")
    lib = MotionLib("data/datasets/dataset_go2_locomotion.yaml", go2, data_paths=DataPaths(test_data))
    assert lib.num_motions() == 7
    w = lib.get_motion_weights()
    assert w.max().item() == pytest.approx(5 / 11)


def test_demo_clip_is_seamless_loop(char):
    lib = MotionLib(DEMO_CLIP, char)
    length = lib.get_motion_length(torch.tensor([0])).item()
    a = lib.calc_motion_frame(torch.tensor([0]), torch.tensor([0.0]))
    b = lib.calc_motion_frame(torch.tensor([0]), torch.tensor([length]))
    torch.testing.assert_close(a.root_pos, b.root_pos, atol=1e-5, rtol=0)
    assert math.isclose(length, 3.0, abs_tol=1e-6)
