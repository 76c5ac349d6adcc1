"""Resampling clips to another frame rate: duration kept, positions lerped, exp maps slerped."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mimickit.anim.mjcf_char_model import load_char_model
from mimickit.anim.motion import LoopMode, Motion
from mimickit.anim.motion_resample import (
    char_expmap_columns,
    resample_frames,
    resample_motion,
    resampled_length,
)
from mimickit.util import torch_util as tu
from tests.conftest import PROJECT_HUMANOID

AXIS = np.array([0.48, -0.6, 0.64])  # unit


def analytic_frames(t: np.ndarray) -> np.ndarray:
    """[root_pos linear in t, root rotation about a fixed axis with an angle linear in t (through π,
    where the stored exp map flips to the other side), one hinge linear in t] → slerp and lerp are
    exact on it."""
    pos = np.stack([0.7 * t, -0.2 * t, 0.9 + 0.1 * t], axis=1)
    angle = 0.5 + 2.5 * t  # passes π at t ≈ 1.06
    q = tu.quat_from_axis_angle(torch.tensor(AXIS).expand(len(t), 3), torch.from_numpy(angle))
    rot = tu.quat_to_exp_map(q).numpy()  # the angle wrapped to [0, π]: the exp map jumps at π
    hinge = (0.3 - 1.2 * t)[:, None]
    return np.concatenate([pos, rot, hinge], axis=1)


def rot_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    qa = tu.exp_map_to_quat(torch.from_numpy(a))
    qb = tu.exp_map_to_quat(torch.from_numpy(b))
    return tu.quat_diff_angle(qa, qb).numpy()


def test_120_to_30_fps_keeps_duration_and_matches_the_motion() -> None:
    t_in = np.arange(181) / 120.0  # 1.5 s
    frames = analytic_frames(t_in)
    out = resample_frames(frames, 120.0, 30.0, expmap_cols=[3])
    assert out.shape == (46, 7)  # 1.5 s · 30 + 1
    assert (out.shape[0] - 1) / 30.0 == pytest.approx((frames.shape[0] - 1) / 120.0)
    expected = analytic_frames(np.arange(46) / 30.0)
    np.testing.assert_allclose(out[:, :3], expected[:, :3], atol=1e-12)
    np.testing.assert_allclose(out[:, 6], expected[:, 6], atol=1e-12)
    assert rot_distance(out[:, 3:6], expected[:, 3:6]).max() < 1e-6


def test_upsampling_slerps_between_frames_across_the_exp_map_flip() -> None:
    t_in = np.arange(31) / 30.0 * 1.6  # 30 intervals over 1.6 s: the rotation passes π in between
    frames = analytic_frames(t_in)
    fps_in = 30 / 1.6
    out = resample_frames(frames, fps_in, 100.0, expmap_cols=[3])
    assert out.shape[0] == resampled_length(31, fps_in, 100.0) == 161
    expected = analytic_frames(np.arange(161) / 100.0)
    assert rot_distance(out[:, 3:6], expected[:, 3:6]).max() < 1e-6
    # A plain lerp of the exp maps would cut through the flip at π: the slerp must not.
    lerped = np.interp(np.arange(161) / 100.0, t_in, frames[:, 3])
    assert np.abs(lerped - out[:, 3]).max() > 0.1


def test_duration_not_a_whole_number_of_output_frames() -> None:
    frames = analytic_frames(np.arange(125) / 120.0)  # 124/120 s = 1.0333 s → 31.0 frames at 30 fps
    assert resample_frames(frames, 120.0, 30.0, [3]).shape[0] == 32
    frames = analytic_frames(np.arange(123) / 120.0)  # 1.0167 s → 30.5 → 31 intervals, 1.0333 s (half a frame)
    out = resample_frames(frames, 120.0, 30.0, [3])
    assert abs((out.shape[0] - 1) / 30.0 - 122 / 120.0) <= 0.5 / 30.0 + 1e-12
    np.testing.assert_allclose(out[-1], frames[-1], atol=1e-12)  # the last sample is clamped to the end


def test_resample_motion_on_humanoid_layout() -> None:
    char = load_char_model(PROJECT_HUMANOID)
    cols = char_expmap_columns(char)
    assert cols == [3, 6, 9, 12, 16, 20, 24, 27, 31]
    rng = np.random.default_rng(0)
    frames = np.cumsum(rng.normal(0.0, 0.02, (121, 34)), axis=0).astype(np.float32)
    m = Motion(LoopMode.WRAP, 120, frames)
    out = resample_motion(m, 30.0, cols)
    assert (out.fps, out.num_frames, out.loop_mode) == (30.0, 31, LoopMode.WRAP)
    assert out.duration == pytest.approx(m.duration)
    np.testing.assert_allclose(out.frames, frames[::4], atol=1e-5)  # every 4th frame is an input frame
    assert resample_motion(m, 120.0, cols) is m
