"""AMASS/SMPL `.npz` → MimicKit SMPL clips.

The judge is SMPL's own forward kinematics, written here independently of the converter (numpy
rotation matrices from Rodrigues' formula, SMPL's joint order and parents, SMPL's Y-up rest frame):
the converted clip posed on MimicKit's `smpl.xml` by the project's batched FK must put every joint
where SMPL puts it. The skeleton's rest offsets are the character's, read in SMPL's rest frame
(SMPL's x, y, z are the character's y, z, x: SMPL faces +z with +y up, the character +x with +z up).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from mimickit.anim.kin_char_model import KinCharModel
from mimickit.anim.mjcf_char_model import load_char_model
from mimickit.tools.smpl_convert import (
    GROUND_CLEARANCE,
    SMPL_JOINTS,
    SMPL_PARENTS,
    SmplPoses,
    convert_smpl,
    load_amass_npz,
    smpl_to_mimickit_frames,
)
from mimickit.util import torch_util as tu
from mimickit.util.errors import MimicKitError

FK_BOUND = 1e-5  # m: float64 pose conversion, float32 character offsets
rng = np.random.default_rng(7)


@pytest.fixture(scope="module")
def smpl_char(test_data: Path) -> KinCharModel:
    return load_char_model(test_data / "assets" / "smpl" / "smpl.xml")


def rodrigues(aa: np.ndarray) -> np.ndarray:
    """Rotation matrices [..., 3, 3] of axis-angles [..., 3]."""
    angle = np.linalg.norm(aa, axis=-1, keepdims=True)
    k = aa / np.maximum(angle, 1e-12)
    K = np.zeros((*aa.shape[:-1], 3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -k[..., 2], k[..., 1], -k[..., 0]
    K = K - np.swapaxes(K, -1, -2)
    s, c = np.sin(angle)[..., None], np.cos(angle)[..., None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def smpl_joint_positions(char: KinCharModel, pose_aa: np.ndarray, trans: np.ndarray) -> np.ndarray:
    """SMPL FK: world joint positions [T, 24, 3] (SMPL order) of axis-angles [T, 24, 3] in a Z-up world."""
    names = char.get_body_names()
    offsets_char = char.local_pos.double().numpy()
    T = pose_aa.shape[0]
    R = rodrigues(pose_aa)
    G = np.zeros((T, 24, 3, 3))
    P = np.zeros((T, 24, 3))
    for s, name in enumerate(SMPL_JOINTS):
        if s == 0:
            G[:, 0], P[:, 0] = R[:, 0], trans
            continue
        x, y, z = offsets_char[names.index(name)]
        offset_smpl = np.array([y, z, x])  # the character's body frame read in SMPL's rest frame
        p = SMPL_PARENTS[s]
        G[:, s] = G[:, p] @ R[:, s]
        P[:, s] = P[:, p] + G[:, p] @ offset_smpl
    return P


def char_joint_positions(char: KinCharModel, frames: np.ndarray) -> np.ndarray:
    """The clip posed by the project's batched FK, reordered to SMPL's joint order: [T, 24, 3]."""
    f = torch.from_numpy(np.asarray(frames, dtype=np.float64))
    with torch.no_grad():
        pos, _ = char.forward_kinematics(f[:, :3], tu.exp_map_to_quat(f[:, 3:6]), char.dof_to_rot(f[:, 6:]))
    names = char.get_body_names()
    return pos.numpy()[:, [names.index(n) for n in SMPL_JOINTS]]


def random_amass(T: int = 40, width: int = 156, fps: float = 120.0) -> dict[str, np.ndarray]:
    """An AMASS-layout motion: a standing-up root (AMASS roots carry SMPL's Y-up→Z-up turn) turning
    about z, joints bent by up to ~0.9 rad about random axes, the root moving on a curve."""
    t = np.arange(T) / fps
    poses = rng.normal(0.0, 0.5, (T, width)) * np.linspace(0.5, 1.0, T)[:, None]
    stand = np.array([np.pi / 2, 0.0, 0.0])  # R_x(90°): SMPL's +y up becomes the world's +z
    turn = 0.8 * t
    root = [rodrigues(np.array([0.0, 0.0, a])) @ rodrigues(stand) for a in turn]
    poses[:, :3] = [_matrix_to_aa(m) for m in root]
    trans = np.stack([0.5 * t, 0.2 * np.sin(3 * t), 0.9 + 0.05 * np.cos(5 * t)], axis=1)
    return {"poses": poses, "trans": trans, "mocap_framerate": np.array(fps)}


def _matrix_to_aa(m: np.ndarray) -> np.ndarray:
    """Axis-angle of a rotation matrix (angles below π; the identity gives zeros)."""
    angle = np.arccos(np.clip((np.trace(m) - 1) / 2, -1, 1))
    if angle < 1e-9:
        return np.zeros(3)
    axis = np.array([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]]) / (2 * np.sin(angle))
    return axis * angle


def test_converted_clip_fk_matches_smpl_fk(smpl_char, tmp_path: Path) -> None:
    data = random_amass(width=72)
    path = tmp_path / "take.npz"
    np.savez(path, **data)
    poses = load_amass_npz(path)
    assert poses.fps == 120.0
    motion = convert_smpl(poses, smpl_char, z_correction="none")
    assert motion.frame_dim == 6 + 69 == 6 + smpl_char.get_dof_size()
    expected = smpl_joint_positions(smpl_char, data["poses"].reshape(-1, 24, 3), data["trans"])
    got = char_joint_positions(smpl_char, smpl_to_mimickit_frames(poses, smpl_char))
    err = np.linalg.norm(got - expected, axis=-1)
    assert err.max() < FK_BOUND, f"worst joint {SMPL_JOINTS[int(err.max(0).argmax())]}: {err.max():.2e} m"
    # The stored (float32) clip too, as MimicKit would read it.
    stored = char_joint_positions(smpl_char, motion.frames)
    assert np.abs(stored - expected).max() < 1e-4


def test_smplh_finger_columns_are_ignored_and_hands_zeroed(smpl_char) -> None:
    data = random_amass(width=156)
    a = smpl_to_mimickit_frames(_poses(data), smpl_char)
    data["poses"][:, 66:] = rng.normal(0.0, 1.0, data["poses"][:, 66:].shape)  # other fingers
    b = smpl_to_mimickit_frames(_poses(data), smpl_char)
    np.testing.assert_array_equal(a, b)
    for hand in ("L_Hand", "R_Hand"):
        joint = smpl_char.get_joint(smpl_char.get_body_id(hand))
        np.testing.assert_array_equal(a[:, 6 + joint.dof_idx : 6 + joint.dof_idx + 3], 0.0)
    expected = smpl_joint_positions(smpl_char, _body_only(data["poses"]), data["trans"])
    assert np.abs(char_joint_positions(smpl_char, a) - expected).max() < FK_BOUND


def test_y_up_input_is_the_same_motion_turned_up(smpl_char) -> None:
    data = random_amass(width=72)
    z_up = smpl_to_mimickit_frames(_poses(data), smpl_char)
    to_y_up = rodrigues(np.array([-np.pi / 2, 0.0, 0.0]))  # the inverse of the converter's R_x(+90°)
    y_data = dict(data)
    y_data["poses"] = data["poses"].copy()
    y_data["poses"][:, :3] = [_matrix_to_aa(to_y_up @ rodrigues(aa)) for aa in data["poses"][:, :3]]
    y_data["trans"] = data["trans"] @ to_y_up.T
    y_up = smpl_to_mimickit_frames(_poses(y_data), smpl_char, up="y")
    np.testing.assert_allclose(char_joint_positions(smpl_char, y_up), char_joint_positions(smpl_char, z_up), atol=1e-6)


def test_z_correction_puts_the_lowest_body_at_the_clearance(smpl_char) -> None:
    data = random_amass(width=72)
    data["trans"][:, 2] += 3.0  # floating
    poses = _poses(data)
    full = convert_smpl(poses, smpl_char, z_correction="full")
    low = char_joint_positions(smpl_char, full.frames)[..., 2].min()
    assert low == pytest.approx(GROUND_CLEARANCE, abs=1e-5)
    calib = convert_smpl(poses, smpl_char, z_correction="calibrate")
    assert char_joint_positions(smpl_char, calib.frames[:30])[..., 2].min() == pytest.approx(GROUND_CLEARANCE, abs=1e-5)


@pytest.mark.parametrize(
    ("change", "key"),
    [
        (lambda d: d.pop("trans"), "'trans'"),
        (lambda d: d.pop("poses"), "'poses'"),
        (lambda d: d.update(poses=d["poses"][:, :30]), "'poses' has shape (40, 30)"),
        (lambda d: d.update(trans=d["trans"][:, :2]), "'trans' has shape (40, 2)"),
        (lambda d: d.pop("mocap_framerate"), "mocap_framerate"),
        (lambda d: d.update(mocap_framerate=np.array(-5.0)), "'mocap_framerate'"),
        (lambda d: d["poses"].__setitem__((3, 4), np.nan), "'poses' holds a non-finite value in frame 3"),
    ],
)
def test_bad_amass_file_is_one_error_naming_file_and_key(tmp_path: Path, change, key: str) -> None:
    data = random_amass(width=72)
    change(data)
    path = tmp_path / "bad.npz"
    np.savez(path, **data)
    with pytest.raises(MimicKitError) as e:
        load_amass_npz(path)
    assert str(path) in str(e.value) and key in str(e.value)


def test_mocap_frame_rate_key_of_smplx_files(tmp_path: Path) -> None:
    data = random_amass(width=165)
    data["mocap_frame_rate"] = data.pop("mocap_framerate")
    np.savez(tmp_path / "x.npz", **data)
    assert load_amass_npz(tmp_path / "x.npz").fps == 120.0


def test_not_the_smpl_character_is_refused(test_data: Path) -> None:
    humanoid = load_char_model(test_data / "assets" / "humanoid" / "humanoid.xml")
    with pytest.raises(MimicKitError, match="not an SMPL joint"):
        smpl_to_mimickit_frames(_poses(random_amass(width=72)), humanoid)


def _poses(data: dict[str, np.ndarray]) -> SmplPoses:
    from mimickit.tools.smpl_convert import smpl_poses_from_arrays

    return smpl_poses_from_arrays(data)


def _body_only(poses: np.ndarray) -> np.ndarray:
    out = np.zeros((poses.shape[0], 24, 3))
    out[:, :22] = poses[:, :66].reshape(-1, 22, 3)
    return out
