"""Generate the project's own demo motion clip for the humanoid: a slow, looping squat.

    python -m mimickit.tools.make_demo_clip [--out data/motions/humanoid_demo_squat.pkl]

The clip is written in MimicKit's .pkl format (a pickled plain dict
``{"loop_mode": 1, "fps": 30, "frames": [[34 floats], ...]}``); each frame is
``[root_pos(3), root_rot exp-map(3), joint dofs(28)]`` with every 3-DoF joint stored as the exponential
map of its local rotation and every hinge as its angle (DoF layout in body order, as MimicKit's clips).

The motion, over one period (default 3 s, 91 frames, first frame == last frame):
  * it starts and ends in the humanoid's init pose (arms down, root at 0.882416 m);
  * the legs bend with the ankle kept straight under the hip joint, so with the root's x/y fixed the
    feet neither slide nor lift: thigh and shin tilt by angles chosen so that their horizontal
    offsets cancel, and the ankle takes the remaining angle so the feet stay flat;
  * pelvis and spine tilt slightly forward, the head keeps looking ahead, the arms swing forward and
    up with a little elbow bend;
  * the root height of every frame is set by forward kinematics (MuJoCo) so that the lowest point of
    the foot boxes sits ``GROUND_CLEARANCE`` above z = 0 (1 mm, as in the init pose).
Everything is a smooth function of ``s(t) = (1 - cos(2 pi t / T)) / 2``, so the loop is seamless
(zero velocity at the top and the bottom). The script is deterministic (no randomness).
"""

from __future__ import annotations

import argparse
import pickle
from pathlib import Path

import mujoco
import numpy as np

REPO_ROOT = Path(__file__).resolve().parents[2]
DEFAULT_CHAR_FILE = REPO_ROOT / "data" / "assets" / "humanoid" / "humanoid.xml"
DEFAULT_OUT = REPO_ROOT / "data" / "motions" / "humanoid_demo_squat.pkl"

FPS = 30
PERIOD_S = 3.0
LOOP_MODE_WRAP = 1

# Lowest foot point above the ground. 1 mm reproduces the init pose's root height exactly
# (0.882416 m = leg length 0.831416 + ankle-to-sole 0.05 + 0.001).
GROUND_CLEARANCE = 0.001
FOOT_BODIES = ("right_foot", "left_foot")

# Motion amplitudes at the bottom of the squat (radians).
THIGH_TILT_MAX = 0.75  # thigh tilt from vertical (knee forward)
TRUNK_LEAN_MAX = 0.08  # forward lean of the trunk, split between pelvis (root) and abdomen
ARM_RAISE_MAX = 1.2  # arms swing forward/up from hanging down
ELBOW_BEND_MAX = 0.3
HEAD_COMPENSATION = 0.6  # fraction of the trunk lean the neck undoes (eyes stay ahead)
ARM_HANG = 1.5708  # shoulder x of the init pose (arms down), the value the env yaml uses


# --------------------------------------------------------------------------------------------------
# rotation helpers (quaternions are w-first, as in MuJoCo)


def axis_angle_quat(axis, angle: float) -> np.ndarray:
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    return np.concatenate([[np.cos(0.5 * angle)], np.sin(0.5 * angle) * axis])


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = np.empty(4)
    mujoco.mju_mulQuat(out, np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))
    return out


def quat_to_exp_map(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q)
    if q[0] < 0.0:
        q = -q
    sin_half = np.linalg.norm(q[1:])
    if sin_half <= 1e-12:
        return np.zeros(3)
    angle = 2.0 * np.arctan2(sin_half, q[0])
    return q[1:] / sin_half * angle


def exp_map_to_quat(e: np.ndarray) -> np.ndarray:
    e = np.asarray(e, dtype=np.float64)
    angle = np.linalg.norm(e)
    if angle <= 1e-12:
        return np.array([1.0, 0.0, 0.0, 0.0])
    return axis_angle_quat(e / angle, angle)


def quat_to_hinge_xyz(q: np.ndarray) -> np.ndarray:
    """Angles (a, b, c) of three successive hinges about x, y, z with R(q) = Rx(a) Ry(b) Rz(c)."""
    mat = np.empty(9)
    mujoco.mju_quat2Mat(mat, np.asarray(q, dtype=np.float64))
    r = mat.reshape(3, 3)
    b = np.arcsin(np.clip(r[0, 2], -1.0, 1.0))
    a = np.arctan2(-r[1, 2], r[2, 2])
    c = np.arctan2(-r[0, 1], r[0, 0])
    return np.array([a, b, c])


# --------------------------------------------------------------------------------------------------
# character layout


class Humanoid:
    """DoF layout of the MJCF character (body order; 3 hinges -> one spherical joint) and FK."""

    def __init__(self, char_file: Path):
        self.model = mujoco.MjModel.from_xml_path(str(char_file))
        self.data = mujoco.MjData(self.model)
        m = self.model
        assert m.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE, "the root body needs a free joint"

        # joints: (name, type, dof column, list of MuJoCo joint ids), in body order
        self.joints: list[tuple[str, str, int, list[int]]] = []
        col = 0
        for body in range(2, m.nbody):
            jids = [j for j in range(m.njnt) if m.jnt_bodyid[j] == body]
            if not jids:
                continue
            assert all(m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE for j in jids)
            if len(jids) == 1:
                self.joints.append((m.joint(jids[0]).name, "hinge", col, jids))
                col += 1
            elif len(jids) == 3:
                for j, axis in zip(jids, np.eye(3), strict=True):
                    assert np.allclose(m.jnt_axis[j], axis), "3-DoF joints must be hinges about x, y, z"
                name = m.joint(jids[0]).name.rsplit("_", 1)[0]
                self.joints.append((name, "spherical", col, jids))
                col += 3
            else:
                raise ValueError(f"unsupported joint count on body {m.body(body).name}")
        self.dof_size = col
        self.col = {name: c for name, _, c, _ in self.joints}

        self.foot_boxes = []
        for name in FOOT_BODIES:
            bid = m.body(name).id
            box = mujoco.mjtGeom.mjGEOM_BOX
            geoms = [g for g in range(m.ngeom) if m.geom_bodyid[g] == bid and m.geom_type[g] == box]
            assert geoms, f"no box geom on {name}"
            self.foot_boxes += geoms

    def frame_to_qpos(self, frame: np.ndarray) -> np.ndarray:
        m = self.model
        qpos = np.zeros(m.nq)
        qpos[0:3] = frame[0:3]
        qpos[3:7] = exp_map_to_quat(frame[3:6])
        dofs = frame[6:]
        for _, kind, c, jids in self.joints:
            # MuJoCo's three hinges of a spherical joint compose as Rx(a) Ry(b) Rz(c)
            spherical = kind == "spherical"
            angles = quat_to_hinge_xyz(exp_map_to_quat(dofs[c : c + 3])) if spherical else dofs[c : c + 1]
            for j, angle in zip(jids, angles, strict=True):
                lo, hi = m.jnt_range[j]
                assert lo - 1e-9 <= angle <= hi + 1e-9, f"{m.joint(j).name}={angle:.4f} outside [{lo}, {hi}]"
                qpos[m.jnt_qposadr[j]] = angle
        return qpos

    def forward(self, frame: np.ndarray) -> mujoco.MjData:
        self.data.qpos[:] = self.frame_to_qpos(frame)
        mujoco.mj_kinematics(self.model, self.data)
        return self.data

    def foot_corners(self) -> np.ndarray:
        """World positions [n_boxes * 8, 3] of the foot box corners (after forward())."""
        d = self.data
        signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)
        out = []
        for g in self.foot_boxes:
            local = signs * self.model.geom_size[g]
            out.append(d.geom_xpos[g] + local @ d.geom_xmat[g].reshape(3, 3).T)
        return np.concatenate(out, axis=0)


# --------------------------------------------------------------------------------------------------
# the clip


def squat_phase(t: np.ndarray, period: float) -> np.ndarray:
    """0 standing -> 1 bottom of the squat -> 0, smooth and periodic."""
    return 0.5 * (1.0 - np.cos(2.0 * np.pi * t / period))


def make_frame(char: Humanoid, s: float, thigh_len: float, shin_len: float) -> np.ndarray:
    frame = np.zeros(6 + char.dof_size)
    dofs = frame[6:]
    col = char.col

    # legs: thigh tilts forward by psi_t, shin by psi_s with thigh_len sin(psi_t) = shin_len sin(psi_s),
    # so the ankle stays directly below the hip (and the root x/y fixed keeps the feet in place)
    psi_t = THIGH_TILT_MAX * s
    psi_s = np.arcsin(thigh_len / shin_len * np.sin(psi_t))
    lean = TRUNK_LEAN_MAX * s
    pelvis_pitch = 0.5 * lean

    frame[3:6] = [0.0, pelvis_pitch, 0.0]  # root: rotation about +y tips the pelvis forward
    dofs[col["abdomen"] + 1] = lean - pelvis_pitch
    dofs[col["neck"] + 1] = -HEAD_COMPENSATION * lean
    for side in ("right", "left"):
        # rotations about y are all in the sagittal plane, so the foot's world pitch is the sum
        # pelvis_pitch + hip + knee + ankle = 0: the foot stays flat
        dofs[col[f"{side}_hip"] + 1] = -psi_t - pelvis_pitch
        dofs[col[f"{side}_knee"]] = psi_t + psi_s
        dofs[col[f"{side}_ankle"] + 1] = -psi_s

    # arms: hang down (shoulder x = +-ARM_HANG), then swing forward/up about the upper arm's local z
    raise_ = ARM_RAISE_MAX * s
    elbow = ELBOW_BEND_MAX * s
    for side, sign in (("right", 1.0), ("left", -1.0)):
        hang = axis_angle_quat([1, 0, 0], sign * ARM_HANG)
        q = quat_mul(hang, axis_angle_quat([0, 0, 1], sign * raise_))
        dofs[col[f"{side}_shoulder"] : col[f"{side}_shoulder"] + 3] = quat_to_exp_map(q)
        dofs[col[f"{side}_elbow"]] = sign * elbow
    return frame


def place_on_ground(char: Humanoid, frame: np.ndarray) -> np.ndarray:
    frame = frame.copy()
    frame[2] = 0.0
    char.forward(frame)
    frame[2] = GROUND_CLEARANCE - char.foot_corners()[:, 2].min()
    return frame


def make_clip(char_file: Path = DEFAULT_CHAR_FILE, fps: int = FPS, period: float = PERIOD_S) -> dict:
    char = Humanoid(char_file)
    m = char.model
    thigh_len = float(np.linalg.norm(m.body("right_shin").pos))
    shin_len = float(np.linalg.norm(m.body("right_foot").pos))

    num_intervals = int(round(period * fps))  # clip length = num_intervals / fps
    phase = squat_phase(np.arange(num_intervals + 1) / num_intervals, 1.0)
    frames = np.stack([place_on_ground(char, make_frame(char, s, thigh_len, shin_len)) for s in phase])
    assert np.allclose(frames[-1], frames[0], atol=1e-9)
    frames[-1] = frames[0]  # exact loop

    _check(char, frames)
    return {"loop_mode": LOOP_MODE_WRAP, "fps": fps, "frames": frames.tolist()}


def _check(char: Humanoid, frames: np.ndarray) -> None:
    """Sanity checks: feet flat on the ground and fixed, hinge decomposition consistent."""
    m = char.model
    foot_ids = [m.body(n).id for n in FOOT_BODIES]
    foot_xy = []
    for frame in frames:
        d = char.forward(frame)
        z = char.foot_corners()[:, 2]
        assert abs(z.min() - GROUND_CLEARANCE) < 1e-6
        bottoms = np.sort(z)[: 4 * len(FOOT_BODIES)]
        assert np.ptp(bottoms) < 1e-6, "feet are not flat"
        foot_xy.append(d.xpos[foot_ids, :2].copy())
        # spherical joints: the body's local rotation must equal the exp-map rotation
        dofs = frame[6:]
        for _, kind, c, jids in char.joints:
            if kind != "spherical":
                continue
            body = m.jnt_bodyid[jids[0]]
            parent = m.body_parentid[body]
            rel = np.empty(4)
            mujoco.mju_negQuat(rel, d.xquat[parent])
            rel = quat_mul(rel, d.xquat[body])
            expected = quat_mul(m.body_quat[body], exp_map_to_quat(dofs[c : c + 3]))
            assert min(np.abs(rel - expected).max(), np.abs(rel + expected).max()) < 1e-9
    foot_xy = np.array(foot_xy)
    assert np.ptp(foot_xy, axis=0).max() < 1e-6, "feet slide"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output .pkl file")
    parser.add_argument("--char_file", type=Path, default=DEFAULT_CHAR_FILE, help="humanoid MJCF")
    parser.add_argument("--fps", type=int, default=FPS)
    parser.add_argument("--period", type=float, default=PERIOD_S, help="clip length in seconds")
    args = parser.parse_args(argv)

    clip = make_clip(args.char_file, args.fps, args.period)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with open(args.out, "wb") as f:
        pickle.dump(clip, f)
    frames = np.asarray(clip["frames"])
    num, width = frames.shape
    print(
        f"wrote {args.out}: {num} frames x {width} values, fps {clip['fps']}, "
        f"{(num - 1) / clip['fps']:.2f} s, root height {frames[:, 2].min():.4f}..{frames[:, 2].max():.4f} m"
    )


if __name__ == "__main__":
    main()
