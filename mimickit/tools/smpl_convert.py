"""Convert AMASS / SMPL pose files (`.npz`) into clips of MimicKit's SMPL humanoid (`smpl.xml`).

Input (the AMASS layout): `poses` [T, 3·K] axis-angles in SMPL joint order (K = 24 for SMPL, 52 for
SMPL-H, 55 for SMPL-X; the first 22 joints are the body), `trans` [T, 3] the root translation, and the
frame rate in `mocap_framerate`, `mocap_frame_rate` or `fps`. No SMPL body model is needed: the pose
conversion uses only the joint rotations and the character's skeleton.

What the conversion does (as MimicKit's `tools/smpl_to_mimickit`):

* SMPL's rest pose is Y-up facing +z (its left is +x); the MuJoCo SMPL character's is Z-up facing +x
  (left +y). A vector in the character's body frame maps into SMPL's by the cyclic permutation
  x→z, y→x, z→y, the quaternion Q = conj(0.5, 0.5, 0.5, 0.5) (x y z w). Every global rotation is
  right-multiplied by Q, G' = G ⊗ Q, so a parent-relative rotation becomes L' = Q⁻¹ ⊗ L ⊗ Q and the
  root R' = R ⊗ Q.
* The world: AMASS is Z-up, `trans` is the root position as it is. `up="y"` takes a Y-up world
  (exports of some other tools): positions and the root are turned by R_x(+90°) first.
* Hands: SMPL's own hand joints (22, 23) are kept for a 72-wide `poses`; for SMPL-H/SMPL-X the
  columns after the 22 body joints are finger/face joints, and the character's hands are zeroed.
* DoFs: each SMPL joint goes to the character's body of the same name (L_Hip, ..., R_Hand), as an
  exponential map, in the character's DoF order; the character's parents must be SMPL's.
* Height (`z_correction`): `calibrate` lowers/raises the clip so that the lowest body origin over the
  first 30 frames is 2.5 cm above the ground, `full` over all frames, `none` leaves `trans` as it is.
"""

from __future__ import annotations

import math
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from mimickit.anim.kin_char_model import JointType, KinCharModel
from mimickit.anim.motion import MAX_CLIP_BYTES, LoopMode, Motion
from mimickit.util import torch_util as tu
from mimickit.util.errors import MimicKitError

# SMPL's joint order in `poses` and its kinematic tree (the standard SMPL kintree).
SMPL_JOINTS = [
    "Pelvis", "L_Hip", "R_Hip", "Torso", "L_Knee", "R_Knee", "Spine", "L_Ankle", "R_Ankle", "Chest",
    "L_Toe", "R_Toe", "Neck", "L_Thorax", "R_Thorax", "Head", "L_Shoulder", "R_Shoulder", "L_Elbow",
    "R_Elbow", "L_Wrist", "R_Wrist", "L_Hand", "R_Hand",
]  # fmt: skip
SMPL_PARENTS = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21]
NUM_BODY_JOINTS = 22  # joints 0..21: the body without SMPL's hand joints
FPS_KEYS = ("mocap_framerate", "mocap_frame_rate", "fps")
Z_CORRECTIONS = ("none", "calibrate", "full")
CALIBRATE_FRAMES = 30
GROUND_CLEARANCE = 0.025  # the lowest body origin ends this high (the foot geometry lies below it)

_Q_REST = (-0.5, -0.5, -0.5, 0.5)  # conj(0.5, 0.5, 0.5, 0.5): SMPL rest frame → the character's
_HALF = math.sqrt(0.5)
_Y_UP_TO_Z_UP = (_HALF, 0.0, 0.0, _HALF)  # R_x(+90°)


@dataclass
class SmplPoses:
    """The arrays of an AMASS-layout file: axis-angles [T, 24, 3] (SMPL order), trans [T, 3], fps."""

    pose_aa: np.ndarray
    trans: np.ndarray
    fps: float
    source: str


def load_amass_npz(path: str | Path, *, input_fps: float | None = None) -> SmplPoses:
    """Read and check an AMASS `.npz` (numpy arrays only: pickled objects in it are never loaded)."""
    p = Path(path)
    if not p.is_file():
        raise MimicKitError(f"SMPL motion file not found: {p}")
    if p.stat().st_size > MAX_CLIP_BYTES:
        raise MimicKitError(f"{p}: {p.stat().st_size} bytes is over the {MAX_CLIP_BYTES}-byte limit for a clip")
    try:
        with np.load(p, allow_pickle=False) as data:
            arrays = {k: _read_key(data, k, p) for k in ("poses", "trans", *FPS_KEYS) if k in data.files}
    except (OSError, ValueError, zipfile.BadZipFile) as e:
        raise MimicKitError(f"{p}: not a readable .npz file ({e})") from None
    return smpl_poses_from_arrays(arrays, source=str(p), input_fps=input_fps)


def _read_key(data: np.lib.npyio.NpzFile, key: str, p: Path) -> np.ndarray:
    try:
        return np.asarray(data[key])
    except ValueError:  # an object array: would need pickle
        raise MimicKitError(f"{p}: key '{key}' holds Python objects, not numbers") from None


def smpl_poses_from_arrays(
    arrays: dict[str, np.ndarray], *, source: str = "<arrays>", input_fps: float | None = None
) -> SmplPoses:
    """Check the AMASS arrays; every problem is one MimicKitError naming `source` and the key."""
    for key in ("poses", "trans"):
        if key not in arrays:
            raise MimicKitError(f"{source}: missing key '{key}' (an AMASS file has poses, trans, mocap_framerate)")
    poses = _numeric(arrays["poses"], source, "poses")
    trans = _numeric(arrays["trans"], source, "trans")
    if poses.ndim != 2 or poses.shape[1] < 3 * NUM_BODY_JOINTS or poses.shape[1] % 3:
        raise MimicKitError(
            f"{source}: key 'poses' has shape {poses.shape}; expected [frames, 3·joints] with at least "
            f"{3 * NUM_BODY_JOINTS} columns (72 SMPL, 156 SMPL-H)"
        )
    if trans.shape != (poses.shape[0], 3):
        raise MimicKitError(f"{source}: key 'trans' has shape {trans.shape}; expected ({poses.shape[0]}, 3)")
    if poses.shape[0] < 2:
        raise MimicKitError(f"{source}: key 'poses' has {poses.shape[0]} frame(s); a clip needs at least 2")
    for key, a in (("poses", poses), ("trans", trans)):
        if not np.isfinite(a).all():
            raise MimicKitError(f"{source}: key '{key}' holds a non-finite value in frame {_first_bad_row(a)}")
    fps = input_fps if input_fps is not None else _fps(arrays, source)
    # SMPL's hand joints are the last two of a 72-wide pose; wider layouts put fingers there instead.
    joints = 24 if poses.shape[1] == 72 else NUM_BODY_JOINTS
    pose_aa = np.zeros((poses.shape[0], 24, 3))
    pose_aa[:, :joints] = poses[:, : 3 * joints].reshape(-1, joints, 3)
    return SmplPoses(pose_aa, trans.copy(), fps, source)


def _numeric(a: np.ndarray, source: str, key: str) -> np.ndarray:
    if not np.issubdtype(np.asarray(a).dtype, np.number):
        raise MimicKitError(f"{source}: key '{key}' is not numeric (dtype {np.asarray(a).dtype})")
    return np.asarray(a, dtype=np.float64)


def _first_bad_row(a: np.ndarray) -> int:
    return int(np.where(~np.isfinite(a).all(axis=1))[0][0])


def _fps(arrays: dict[str, np.ndarray], source: str) -> float:
    key = next((k for k in FPS_KEYS if k in arrays), None)
    if key is None:
        raise MimicKitError(f"{source}: no frame rate: none of the keys {', '.join(FPS_KEYS)} (or give --input_fps)")
    value = np.asarray(arrays[key])
    if value.size != 1 or not np.issubdtype(value.dtype, np.number):
        raise MimicKitError(f"{source}: key '{key}' must be one number, got {value!r}")
    fps = float(value.reshape(()))
    if not math.isfinite(fps) or fps <= 0:
        raise MimicKitError(f"{source}: key '{key}' must be a positive frame rate, got {fps}")
    return fps


def smpl_dof_map(char: KinCharModel) -> list[int]:
    """For each non-root body of `char` (in order), the SMPL joint of the same name; MimicKitError when
    the character is not SMPL's skeleton (a missing joint, another parent, a joint that is not 3-DoF)."""
    names = char.get_body_names()
    out = []
    for j in range(1, len(names)):
        name = names[j]
        if name not in SMPL_JOINTS:
            raise MimicKitError(f"{char.source}: body '{name}' is not an SMPL joint; is this the SMPL character?")
        s = SMPL_JOINTS.index(name)
        parent = names[char.get_parent_id(j)]
        if parent != SMPL_JOINTS[SMPL_PARENTS[s]]:
            raise MimicKitError(
                f"{char.source}: body '{name}' hangs from '{parent}', SMPL's from '{SMPL_JOINTS[SMPL_PARENTS[s]]}'"
            )
        if char.get_joint(j).type != JointType.SPHERICAL:
            raise MimicKitError(f"{char.source}: joint of body '{name}' is not 3-DoF; SMPL joints are spherical")
        out.append(s)
    if names[0] != SMPL_JOINTS[0] or len(out) != len(SMPL_JOINTS) - 1:
        raise MimicKitError(f"{char.source}: not the SMPL character (root '{names[0]}', {len(names)} bodies)")
    return out


def smpl_to_mimickit_frames(poses: SmplPoses, char: KinCharModel, *, up: str = "z") -> np.ndarray:
    """Pose conversion only: MimicKit SMPL frames [T, 6 + 69] (float64), before any height correction."""
    if up not in ("y", "z"):
        raise ValueError(f"up must be 'y' or 'z', got {up!r}")
    dof_map = smpl_dof_map(char)
    T = poses.pose_aa.shape[0]
    q = tu.exp_map_to_quat(torch.from_numpy(poses.pose_aa))  # [T, 24, 4] parent-relative, SMPL frames
    rest = torch.tensor(_Q_REST, dtype=torch.float64).expand(T, 24, 4)
    local = tu.quat_mul(tu.quat_mul(tu.quat_conjugate(rest), q), rest)  # L' = Q⁻¹ L Q
    root = tu.quat_mul(q[:, 0], rest[:, 0])  # R' = R Q
    pos = torch.from_numpy(poses.trans)
    if up == "y":
        world = torch.tensor(_Y_UP_TO_Z_UP, dtype=torch.float64).expand(T, 4)
        root, pos = tu.quat_mul(world, root), tu.quat_rotate(world, pos)
    joint_rot = local[:, dof_map]  # [T, 23, 4] in the character's body order
    dofs = char.rot_to_dof(joint_rot)
    return torch.cat([pos, tu.quat_to_exp_map(root), dofs], dim=-1).numpy()


def correct_height(frames: np.ndarray, char: KinCharModel, mode: str) -> np.ndarray:
    """Shift the root height so that the lowest body origin (over the first 30 frames, or all) is
    `GROUND_CLEARANCE` above the ground; `none` returns the frames unchanged."""
    if mode not in Z_CORRECTIONS:
        raise ValueError(f"z_correction must be one of {Z_CORRECTIONS}, got {mode!r}")
    if mode == "none":
        return frames
    part = frames[:CALIBRATE_FRAMES] if mode == "calibrate" else frames
    f = torch.from_numpy(np.asarray(part, dtype=np.float64))
    with torch.no_grad():
        body_pos, _ = char.forward_kinematics(f[:, :3], tu.exp_map_to_quat(f[:, 3:6]), char.dof_to_rot(f[:, 6:]))
    out = frames.copy()
    out[:, 2] -= float(body_pos[..., 2].min()) - GROUND_CLEARANCE
    return out


def convert_smpl(
    poses: SmplPoses, char: KinCharModel, *, up: str = "z", z_correction: str = "calibrate",
    loop_mode: LoopMode = LoopMode.WRAP,
) -> Motion:  # fmt: skip
    """An AMASS clip as a MimicKit SMPL Motion at the input's frame rate."""
    frames = smpl_to_mimickit_frames(poses, char, up=up)
    frames = correct_height(frames, char, z_correction)
    return Motion(loop_mode, poses.fps, frames.astype(np.float32))
