"""DeepMimic humanoid3d text clips → MimicKit humanoid clips.

Against the official data (MIMICKIT_TEST_DATA): MimicKit's authors converted the same DeepMimic takes,
so a converted clip and the official .pkl must put every body in the same place (forward kinematics on
the reference humanoid). Measured by benchmarks/deepmimic_convert_report.py:

* 8 takes agree to float32 rounding (worst 0.024 mm, spinkick, whose root travels furthest): bound
  0.1 mm. Body positions cannot see the rotation of a leaf body (head, feet), so local joint rotations
  are compared too: within 1e-3 rad, except the official punch (head, 0.038 rad) and getup_facedown
  (head and feet, <= 0.008 rad), which retouched those.
* 9 takes agree exactly outside a few frames that the official clips retouched (no root change; the
  edits are joint rotations, e.g. the kick's right hip, the loop seams of cartwheel/jump/dance_spin):
  bound 0.1 mm outside those frames, and the measured worst case (+5 %) inside them. jog is the
  exception: every frame differs by a few mm (root up to 6.4 mm), a re-processed take, not an offset.
  roll has one doubled frame duration in the DeepMimic file; the official clip ignores it, so it is
  compared with `resample=False` (the default resamples it to 122 frames).
* walk and crawl are different takes (frame counts differ) and are not compared.
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

import mimickit.util.torch_util as tu
from mimickit.anim.mjcf_char_model import load_char_model
from mimickit.anim.motion import LoopMode, load_motion
from mimickit.tools.deepmimic_convert import (
    convert_deepmimic,
    deepmimic_to_mimickit_frames,
    fk_body_distance,
    fk_body_pos,
    load_deepmimic_text,
)
from mimickit.util.errors import MimicKitError
from tests.conftest import PROJECT_HUMANOID

EXACT_BOUND = 1e-4  # m: float32 rounding of the stored clips (worst measured 2.4e-5 m)
EXACT_TAKES = ["dance_a", "dance_b", "getup_facedown", "getup_faceup", "punch", "run", "spinkick", "zombie_walk"]
EXACT_ROT_BOUND = 1e-3  # rad
LEAF_RETOUCHES = {"punch": 0.0404, "getup_facedown": 0.0083}  # measured + 5 %, head / feet only
LEAF_BODIES = {"head", "right_foot", "left_foot"}
# take: (bound over all frames in m = measured max + 5 %, frames [start, stop) retouched in the official clip)
RETOUCHED_TAKES = {
    "backflip": (0.0486, [(8, 28)]),
    "cartwheel": (0.0026, [(155, 163)]),
    "dance_spin": (0.0057, [(116, 121)]),
    "jump": (0.0023, [(1, 11), (94, 106)]),
    "kick": (0.196, [(16, 36)]),
    "roll": (0.0499, [(0, 21), (78, 121)]),
    "sideflip": (0.0394, [(18, 40)]),
    "spin": (0.0865, [(38, 41), (105, 106)]),
    "jog": (0.0525, [(0, 26)]),  # re-processed throughout, root included
}


# ----------------------------------------------------------------------------------------- helpers
def _identity_frame(dt: float = 1 / 30) -> list[float]:
    f = [dt, 0.0, 0.9, 0.0]
    for n in (4, 4, 4, 4, 1, 4, 4, 1, 4, 1, 4, 4, 1):
        f += [1.0, 0.0, 0.0, 0.0] if n == 4 else [0.0]
    assert len(f) == 44
    return f


def _write(path: Path, obj) -> Path:
    path.write_text(json.dumps(obj))
    return path


@pytest.fixture(scope="module")
def project_char():
    return load_char_model(PROJECT_HUMANOID)


@pytest.fixture(scope="module")
def ref_char(ref_humanoid_xml):
    return load_char_model(ref_humanoid_xml)


def _pair(test_data: Path, take: str, resample: bool = True):
    conv = convert_deepmimic(test_data / "deepmimic_motions" / f"humanoid3d_{take}.txt", resample=resample)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = load_motion(test_data / "motions" / "humanoid" / f"humanoid_{take}.pkl")
    return conv, ref


# ----------------------------------------------------------------------- against the official clips
@pytest.mark.parametrize("take", EXACT_TAKES)
def test_converted_take_matches_official_clip(test_data, ref_char, take):
    conv, ref = _pair(test_data, take)
    assert conv.num_frames == ref.num_frames
    assert conv.fps == ref.fps
    assert conv.loop_mode == ref.loop_mode
    assert conv.frames.shape == ref.frames.shape == (ref.num_frames, 34)
    d = fk_body_distance(ref_char, conv.frames, ref.frames)
    assert d.max().item() < EXACT_BOUND, f"{take}: max FK body difference {d.max().item():.2e} m"
    rot_c = ref_char.dof_to_rot(torch.as_tensor(conv.frames[:, 6:], dtype=torch.float64))
    rot_r = ref_char.dof_to_rot(torch.as_tensor(ref.frames[:, 6:], dtype=torch.float64))
    angle = tu.quat_diff_angle(rot_c, rot_r).max(dim=0).values  # [J-1]
    for j, a in enumerate(angle.tolist()):
        body = ref_char.get_body_names()[j + 1]
        bound = LEAF_RETOUCHES.get(take, EXACT_ROT_BOUND) if body in LEAF_BODIES else EXACT_ROT_BOUND
        assert a < bound, f"{take}: {body} joint rotation differs by {a:.4f} rad"


@pytest.mark.parametrize("take", sorted(RETOUCHED_TAKES))
def test_converted_take_matches_official_clip_outside_retouched_frames(test_data, ref_char, take):
    bound, ranges = RETOUCHED_TAKES[take]
    conv, ref = _pair(test_data, take, resample=take != "roll")
    assert conv.num_frames == ref.num_frames
    assert conv.fps == ref.fps
    assert conv.loop_mode == ref.loop_mode
    d = fk_body_distance(ref_char, conv.frames, ref.frames)
    assert d.max().item() < bound, f"{take}: max FK body difference {d.max().item():.4f} m"
    untouched = torch.ones(conv.num_frames, dtype=torch.bool)
    for a, b in ranges:
        untouched[a:b] = False
    if untouched.any():
        assert d[untouched].max().item() < EXACT_BOUND
    if take != "jog":  # the retouches are joint rotations: the root is the converted one
        assert d[:, 0].max().item() < EXACT_BOUND


def test_roll_uneven_frame_duration_is_resampled(test_data):
    clip = load_deepmimic_text(test_data / "deepmimic_motions" / "humanoid3d_roll.txt")
    duration = clip.dts[:-1].sum()  # one frame lasts 2 / 60 s
    m = convert_deepmimic(test_data / "deepmimic_motions" / "humanoid3d_roll.txt")
    assert m.fps == 60
    assert m.num_frames == round(duration * 60) + 1 == 122


def test_different_takes_differ_in_length(test_data):
    for take in ("walk", "crawl"):
        conv, ref = _pair(test_data, take)
        assert conv.num_frames != ref.num_frames


# -------------------------------------------------------------------------------- conventions
def test_zero_pose_hangs_the_arms_and_stands_z_up(project_char):
    """DeepMimic's zero pose (arms down, y-up) becomes an upright MimicKit pose with the arms down."""
    frames = deepmimic_to_mimickit_frames(np.array([_identity_frame()]))
    np.testing.assert_allclose(frames[0, :3], [0.0, 0.0, 0.9], atol=1e-12)  # y-up height → z
    np.testing.assert_allclose(frames[0, 3:6], 0.0, atol=1e-12)
    # shoulders turn MimicKit's T-pose arm down: ±90° about x
    np.testing.assert_allclose(frames[0, 12:15], [math.pi / 2, 0, 0], atol=1e-9)
    np.testing.assert_allclose(frames[0, 16:19], [-math.pi / 2, 0, 0], atol=1e-9)
    pos = fk_body_pos(project_char, frames)[0]
    names = project_char.get_body_names()
    for side in ("right", "left"):
        shoulder = pos[names.index(f"{side}_upper_arm")]
        hand = pos[names.index(f"{side}_hand")]
        np.testing.assert_allclose((hand - shoulder).numpy(), [0, 0, -(0.274788 + 0.258947)], atol=1e-9)
    assert pos[names.index("head")][2] > pos[0][2] > pos[names.index("right_foot")][2]


def test_hinge_signs_follow_mimickit_ranges():
    """DeepMimic knees bend negative about z, elbows positive; MimicKit knees positive about y, the right
    elbow positive and the left negative about z."""
    f = _identity_frame()
    f[20] = f[34] = -1.0  # knees
    f[29] = f[43] = 0.5  # elbows
    mk = deepmimic_to_mimickit_frames(np.array([f]))[0]
    assert mk[23] == pytest.approx(1.0) and mk[30] == pytest.approx(1.0)  # right_knee, left_knee
    assert mk[15] == pytest.approx(0.5) and mk[19] == pytest.approx(-0.5)  # right_elbow, left_elbow


def test_fps_and_loop_mode_carried_over(tmp_path):
    frames = [_identity_frame(1 / 60) for _ in range(5)]
    frames[-1][0] = 0.0
    wrap = convert_deepmimic(_write(tmp_path / "a.txt", {"Loop": "wrap", "Frames": frames}))
    assert wrap.loop_mode == LoopMode.WRAP and wrap.fps == 60 and wrap.num_frames == 5
    none = convert_deepmimic(_write(tmp_path / "b.txt", {"Loop": "none", "Frames": frames}))
    assert none.loop_mode == LoopMode.CLAMP
    assert none.frames.dtype == np.float32 and none.frames.shape == (5, 34)


def test_uneven_durations_are_resampled_with_slerp(tmp_path):
    frames = [_identity_frame(1 / 30) for _ in range(5)]
    frames[2][0] = 2 / 30  # frame 3 starts at 4/30 s: one frame missing
    frames[-1][0] = 0.0
    for i, f in enumerate(frames):
        t = [0, 1, 2, 4, 5][i] / 30
        f[1] = t  # root x moves 1 m/s
        f[20] = -t  # right knee
        half = 0.5 * 3.0 * t  # root turns 3 rad/s about y (DeepMimic up)
        f[4:8] = [math.cos(half), 0.0, math.sin(half), 0.0]
    m = convert_deepmimic(_write(tmp_path / "u.txt", {"Loop": "wrap", "Frames": frames}))
    assert m.fps == 30 and m.num_frames == 6
    t = np.arange(6) / 30
    np.testing.assert_allclose(m.frames[:, 0], t, atol=1e-6)
    np.testing.assert_allclose(m.frames[:, 23], t, atol=1e-6)  # knee sign flipped
    np.testing.assert_allclose(m.frames[:, 3:6], np.stack([0 * t, 0 * t, 3 * t], 1), atol=1e-6)  # yaw z
    kept = convert_deepmimic(tmp_path / "u.txt", resample=False)
    assert kept.num_frames == 5


def test_rotation_round_trip_matches_fk_of_deepmimic_skeleton(project_char):
    """A random pose: MimicKit FK of the converted frame equals DeepMimic FK (its own skeleton,
    y-up) rotated into z-up, for every body."""
    g = torch.Generator().manual_seed(0)
    f = torch.tensor(_identity_frame(), dtype=torch.float64)
    for c in (4, 8, 12, 16, 21, 25, 30, 35, 39):
        f[c : c + 4] = tu.quat_normalize(torch.randn(4, generator=g, dtype=torch.float64))
    for c in (20, 29, 34, 43):
        f[c] = float(torch.rand(1, generator=g)) * 2 - 1
    f[1:4] = torch.tensor([0.3, 0.8, -0.2])
    # DeepMimic FK: (parent column, offset in parent frame, joint column, hinge?) in MimicKit body order
    dm = {
        "pelvis": (None, None, 4, False),
        "torso": ("pelvis", (0, 0.236151, 0), 8, False),
        "head": ("torso", (0, 0.223894, 0), 12, False),
        "right_upper_arm": ("torso", (-0.02405, 0.2435, 0.18311), 25, False),
        "right_lower_arm": ("right_upper_arm", (0, -0.274788, 0), 29, True),
        "right_hand": ("right_lower_arm", (0, -0.258947, 0), None, False),
        "left_upper_arm": ("torso", (-0.02405, 0.2435, -0.18311), 39, False),
        "left_lower_arm": ("left_upper_arm", (0, -0.274788, 0), 43, True),
        "left_hand": ("left_lower_arm", (0, -0.258947, 0), None, False),
        "right_thigh": ("pelvis", (0, 0, 0.084887), 16, False),
        "right_shin": ("right_thigh", (0, -0.421546, 0), 20, True),
        "right_foot": ("right_shin", (0, -0.40987, 0), 21, False),
        "left_thigh": ("pelvis", (0, 0, -0.084887), 30, False),
        "left_shin": ("left_thigh", (0, -0.421546, 0), 34, True),
        "left_foot": ("left_shin", (0, -0.40987, 0), 35, False),
    }
    z = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    pos, rot = {}, {}
    for name, (parent, off, col, hinge) in dm.items():
        if col is None:
            q = tu.quat_identity(()).double()
        elif hinge:
            q = tu.quat_from_axis_angle(z, f[col])
        else:
            q = tu.quat_normalize(tu.quat_from_wxyz(f[col : col + 4]))
        if parent is None:
            pos[name], rot[name] = f[1:4], q
        else:
            pos[name] = pos[parent] + tu.quat_rotate(rot[parent], torch.tensor(off, dtype=torch.float64))
            rot[name] = tu.quat_mul(rot[parent], q)
    to_zup = torch.tensor([math.sqrt(0.5), 0, 0, math.sqrt(0.5)], dtype=torch.float64)
    expected = torch.stack([tu.quat_rotate(to_zup, pos[n]) for n in project_char.get_body_names()])
    got = fk_body_pos(project_char, deepmimic_to_mimickit_frames(f[None].numpy()))[0]
    torch.testing.assert_close(got, expected, atol=1e-6, rtol=0)  # model offsets are float32


# ------------------------------------------------------------------------------------- errors
@pytest.mark.parametrize(
    "content, message",
    [
        ("this is not json {", "not JSON"),
        (json.dumps({"Loop": "wrap", "Frames": [[0.1] * 43, [0.0] * 43]}), "width 43"),
        (json.dumps({"Loop": "wrap"}), "missing key(s) Frames"),
        (json.dumps({"Frames": [_identity_frame()] * 2}), "missing key(s) Loop"),
        (json.dumps({"Loop": "mirror", "Frames": [_identity_frame()] * 2}), "Loop must be"),
        (json.dumps([1, 2, 3]), "expected a JSON object"),
        (json.dumps({"Loop": "wrap", "Frames": []}), "non-empty"),
        (json.dumps({"Loop": "wrap", "Frames": [_identity_frame(0.0)] * 3}), "no frame rate"),
    ],
)
def test_bad_files_raise_one_error_naming_the_file(tmp_path, content, message):
    path = tmp_path / "humanoid3d_bad.txt"
    path.write_text(content)
    with pytest.raises(MimicKitError) as e:
        convert_deepmimic(path)
    assert str(path) in str(e.value)
    assert message in str(e.value)


def test_missing_file_raises(tmp_path):
    with pytest.raises(MimicKitError, match="not found"):
        convert_deepmimic(tmp_path / "nope.txt")
