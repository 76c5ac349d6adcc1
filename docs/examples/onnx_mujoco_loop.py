"""Run a policy exported by `mimickit export onnx` in a plain MuJoCo loop: numpy, mujoco and onnxruntime
only, no MimicKit import. It reproduces the DeepMimic observation (global observations: the character's
state, then the clip 1, 2, 3 control steps ahead) from MjData and the clip frames that `--mujoco_out`
wrote, feeds it to the ONNX graph, writes its PD targets into the position actuators and steps MuJoCo.
It prints the mean body position error against the clip (`pos_err_m`, as `mimickit test` reports it).

    mimickit export onnx data/models/deepmimic_go2_pace_model.pt --arg_file data/models/deepmimic_go2_pace_model.txt \
        --data_dir ../shared/data --out go2.onnx --mujoco_out go2_sim.npz
    python docs/examples/onnx_mujoco_loop.py go2.onnx go2_sim.npz --episodes 4
"""

from __future__ import annotations

import argparse
import sys

import mujoco
import numpy as np
import onnxruntime as ort


def load_sim(path: str) -> tuple[mujoco.MjModel, mujoco.MjData, dict[str, np.ndarray]]:
    """The scene (from the .mjb bytes inside the .npz), a fresh MjData, and the layout and clip arrays."""
    with np.load(path, allow_pickle=False) as f:
        sim = {k: f[k] for k in f.files}
    m = mujoco.MjModel.from_binary_path("scene.mjb", {"scene.mjb": sim.pop("mjb").tobytes()})
    return m, mujoco.MjData(m), sim


def tan_norm(q: np.ndarray) -> np.ndarray:
    """Quaternions [..., 4] (x y z w) → [..., 6]: the rotated x axis, then the rotated z axis."""
    x, y, z, w = np.moveaxis(q, -1, 0)
    return np.stack(
        [1 - 2 * (y * y + z * z), 2 * (x * y + z * w), 2 * (x * z - y * w),
         2 * (x * z + y * w), 2 * (y * z - x * w), 1 - 2 * (x * x + y * y)],
        axis=-1,
    )  # fmt: skip


def character_state(m: mujoco.MjModel, d: mujoco.MjData, sim: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Root pose and (centre-of-mass, world-frame) velocities, local joint rotations (x y z w), DoF
    velocities and body positions, from MjData after `mj_kinematics` / `mj_comPos` / `mj_comVel`."""
    root = int(sim["body_ids"][0])
    vel6 = np.zeros(6)  # angular then linear velocity of the root's centre of mass, world frame
    mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_BODY, root, vel6, 0)
    joint_rot = np.zeros((len(sim["body_ids"]) - 1, 4))
    joint_rot[:, 3] = 1.0
    half = 0.5 * d.qpos[sim["hinge_qpos"]][:, None]
    joint_rot[sim["hinge_joints"]] = np.concatenate([sim["hinge_axes"] * np.sin(half), np.cos(half)], axis=-1)
    if len(sim["ball_joints"]):
        joint_rot[sim["ball_joints"]] = d.qpos[sim["ball_qpos"]][:, [1, 2, 3, 0]]
    body_pos = d.xpos[sim["body_ids"]].copy()
    return {
        "root_pos": body_pos[0], "root_rot": d.xquat[root][[1, 2, 3, 0]], "root_vel": vel6[3:],
        "root_ang_vel": vel6[:3], "joint_rot": joint_rot, "dof_vel": d.qvel[sim["dof_qvel"]], "body_pos": body_pos,
    }  # fmt: skip


def observation(s: dict[str, np.ndarray], sim: dict[str, np.ndarray], i: int) -> np.ndarray:
    """The env's observation at clip step i: the character's features, then each target frame's."""
    key = sim["key_ids"]
    height = [s["root_pos"][2:3]] if sim["root_height_obs"] else []
    parts = [
        *height, tan_norm(s["root_rot"]), s["root_vel"], s["root_ang_vel"], tan_norm(s["joint_rot"]).ravel(),
        s["dof_vel"], (s["body_pos"][key] - s["root_pos"]).ravel(),
    ]  # fmt: skip
    for t in i + sim["tar_obs_steps"]:
        tar_pos, rel = sim["ref_root_pos"][t], sim["ref_root_pos"][t] - s["root_pos"]
        rel = np.concatenate([rel[:2], tar_pos[2:3]]) if sim["root_height_obs"] else rel[:2]
        rots = np.concatenate([sim["ref_root_rot"][t][None], sim["ref_joint_rot"][t]])
        tar_key = sim["ref_body_pos"][t][key] - tar_pos
        parts += [rel, tan_norm(rots).ravel(), tar_key.ravel()]
    return np.concatenate(parts).astype(np.float32)


def pos_error(s: dict[str, np.ndarray], sim: dict[str, np.ndarray], i: int) -> float:
    """Mean over bodies of the root-relative body position error (the root's own term is 0), metres."""
    ref = sim["ref_body_pos"][i]
    rel_err = (s["body_pos"] - s["root_pos"]) - (ref - ref[0])
    return float(np.linalg.norm(rel_err, axis=-1).mean())


def reset(m: mujoco.MjModel, d: mujoco.MjData, sim: dict[str, np.ndarray], i: int) -> None:
    """The character onto clip frame i (its pose and velocities), as the env's reset puts it."""
    d.qpos[:], d.qvel[:] = sim["ref_qpos"][i], sim["ref_qvel"][i]
    update_kinematics(m, d)


def update_kinematics(m: mujoco.MjModel, d: mujoco.MjData) -> None:
    """Body poses and velocities of the current qpos/qvel (mj_step leaves them one substep behind)."""
    mujoco.mj_kinematics(m, d)
    mujoco.mj_comPos(m, d)
    mujoco.mj_comVel(m, d)


def run_episode(
    policy: ort.InferenceSession, m: mujoco.MjModel, d: mujoco.MjData, sim: dict[str, np.ndarray], start: int
) -> list[float]:
    """One episode from clip step `start` (until the episode's time limit or the clip's end): the body
    position error after each control step."""
    steps = int(sim["episode_steps"])
    if not sim["clip_wraps"]:
        steps = min(steps, int(sim["clip_steps"]) - start)
    reset(m, d, sim, start)
    errors = []
    for i in range(start, start + steps):
        obs = observation(character_state(m, d, sim), sim, i)
        (action,) = policy.run(["action"], {"obs": obs[None]})
        d.ctrl[sim["act_ids"]] = action[0]
        mujoco.mj_step(m, d, int(sim["substeps"]))
        update_kinematics(m, d)
        errors.append(pos_error(character_state(m, d, sim), sim, i + 1))
    return errors


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("onnx", help="the policy (.onnx) of `mimickit export onnx`")
    p.add_argument("sim", help="its --mujoco_out file (.npz)")
    p.add_argument("--episodes", type=int, default=4, help="episodes from start frames spread over the clip")
    args = p.parse_args(argv)
    policy = ort.InferenceSession(args.onnx, providers=["CPUExecutionProvider"])
    meta = policy.get_modelmeta().custom_metadata_map
    m, d, sim = load_sim(args.sim)
    reset(m, d, sim, 0)
    obs_dim = len(observation(character_state(m, d, sim), sim, 0))
    if obs_dim != int(meta["obs_dim"]):
        sys.exit(f"error: {args.sim} makes {obs_dim} observations, {args.onnx} takes {meta['obs_dim']}: not one export")
    starts = np.linspace(0, int(sim["clip_steps"]) - 1, args.episodes, endpoint=False).astype(int)
    errors = [run_episode(policy, m, d, sim, int(s)) for s in starts]
    flat = np.concatenate(errors)
    print(f"{meta.get('model_file', args.onnx)} ({meta.get('env_name')} at {meta.get('control_freq')} Hz):")
    print(f"  {len(starts)} episodes, {len(flat)} steps, mean pos_err_m {flat.mean():.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
