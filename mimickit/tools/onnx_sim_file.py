"""What a plain MuJoCo loop needs to run an exported DeepMimic policy without MimicKit, in one .npz
(`mimickit export onnx --mujoco_out`; read by `docs/examples/onnx_mujoco_loop.py`):

* `mjb`: the compiled scene the MuJoCo engine simulates (floor, character, one position actuator per DoF
  with the character's PD gains, the physics options), as MuJoCo's binary model (bytes, uint8), so that
  the loop steps the very model the policy was trained in. An .mjb is read by the MuJoCo version that
  wrote it.
* where the character lives in it: `body_ids` [J] (MuJoCo body ids in the kinematic order of the
  observations), `key_ids` [K] (indices into them), hinge and ball joint addresses, `dof_qvel` [D],
  `act_ids` [D];
* the reference clip at every control step from time 0: `ref_root_pos` [F, 3], `ref_root_rot` [F, 4]
  (x y z w), `ref_joint_rot` [F, J-1, 4], `ref_body_pos` [F, J, 3], and the MuJoCo state of each frame
  (`ref_qpos`, `ref_qvel`), which is how the env resets the character onto the clip;
* the observation settings (`root_height_obs`, `tar_obs_steps`), `dt`, `substeps`, `episode_steps`,
  `clip_steps` (control steps from time 0 to the clip's end), `clip_wraps` (whether it loops: an episode
  of a clip that does not ends at its end).

Only the observation layout the example reproduces is accepted: a DeepMimic env with global observations
and no phase observation, one clip, the MuJoCo engine in `pos` control mode.
"""

from __future__ import annotations

import io
import math
import os
import tempfile
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import torch

from mimickit.anim.motion import LoopMode
from mimickit.engines.engine import ControlMode
from mimickit.util.errors import MimicKitError


def write_sim_file(inputs: Any, out: Path) -> None:
    """Build one env of `inputs` (a `RunInputs`) and write its scene, layout and clip to `out`."""
    from mimickit.envs.env_builder import build_env

    env = build_env(inputs.env_file, inputs.engine_file, 1, "cpu", False, inputs.data_paths, inputs.motion_file)
    try:
        check_supported(env)
        arrays = {"mjb": np.frombuffer(model_bytes(env.engine.mj_model), dtype=np.uint8)}
        arrays.update(layout_arrays(env))
        arrays.update(clip_arrays(env))
    finally:
        env.engine.close()
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_bytes(buf.getvalue())
    tmp.replace(out)


def check_supported(env: Any) -> None:
    """MimicKitError naming the first setting the plain-MuJoCo example does not reproduce."""
    from mimickit.envs.deepmimic_env import DeepMimicEnv

    cfg = env.config
    problems = [
        (type(env) is not DeepMimicEnv, f"env {cfg.env_name!r} is not the DeepMimic env"),
        (env.engine.get_name() != "mujoco", f"engine {env.engine.get_name()!r} is not MuJoCo"),
        (env.engine.get_control_mode() != ControlMode.pos, "the engine's control_mode is not 'pos'"),
        (not getattr(cfg, "global_obs", False), "global_obs is off"),
        (getattr(cfg, "enable_phase_obs", False), "enable_phase_obs is on"),
    ]
    for bad, why in problems:
        if bad:
            raise MimicKitError(f"--mujoco_out: {why}; the plain-MuJoCo example reproduces DeepMimic's global obs")
    if env.motion_lib.num_motions() != 1:
        raise MimicKitError(f"--mujoco_out: the env tracks {env.motion_lib.num_motions()} clips; give one clip")


def model_bytes(m: mujoco.MjModel) -> bytes:
    """The compiled model as MuJoCo's binary format (mj_saveModel writes to a file only)."""
    fd, name = tempfile.mkstemp(suffix=".mjb")
    os.close(fd)
    try:
        mujoco.mj_saveModel(m, name, None)
        return Path(name).read_bytes()
    finally:
        os.unlink(name)


def layout_arrays(env: Any) -> dict[str, np.ndarray]:
    lay = env.engine.obj_layout(env.get_char_id())
    cfg = env.config
    char = env.char_model
    dt = env.engine.get_timestep()
    return {
        "body_ids": lay.body_ids,
        "key_ids": np.array([char.get_body_id(b) for b in cfg.key_bodies], dtype=np.int64),
        "hinge_qpos": lay.hinge_qpos, "hinge_joints": lay.hinge_joints, "hinge_axes": lay.hinge_axes,
        "ball_qpos": lay.ball_qpos, "ball_joints": lay.ball_joints,
        "dof_qvel": lay.dof_qvel, "act_ids": lay.act_ids,
        "root_height_obs": np.array(bool(cfg.root_height_obs)),
        "tar_obs_steps": np.array(cfg.tar_obs_steps if cfg.enable_tar_obs else [], dtype=np.int64),
        "dt": np.array(dt),
        "substeps": np.array(env.engine.config.substeps),
        "episode_steps": np.array(math.ceil(cfg.episode_length / dt - 1e-6)),
    }  # fmt: skip


def clip_arrays(env: Any) -> dict[str, np.ndarray]:
    """The clip at times i·dt, i = 0 .. F-1: every step an episode from any start can look at (targets
    ahead included), and the MuJoCo state the env's reset would set for each frame."""
    lib, dt = env.motion_lib, env.engine.get_timestep()
    ids = torch.zeros(1, dtype=torch.long)
    length = float(lib.get_motion_length(ids)[0])
    wrap = int(lib.get_motion_loop_mode(ids)[0]) == int(LoopMode.WRAP)
    clip_steps = math.ceil(length / dt - 1e-6)
    ahead = max(env.config.tar_obs_steps, default=0) + 1
    frames = clip_steps + (math.ceil(env.config.episode_length / dt) if wrap else 0) + ahead
    times = torch.arange(frames, dtype=torch.float32) * dt
    f = lib.calc_motion_frame(ids.expand(frames), times)
    body_pos, _ = env.char_model.forward_kinematics(f.root_pos, f.root_rot, f.joint_rot)
    qpos, qvel = reset_states(env, f)
    return {
        "ref_root_pos": f.root_pos.numpy(), "ref_root_rot": f.root_rot.numpy(),
        "ref_joint_rot": f.joint_rot.numpy(), "ref_body_pos": body_pos.numpy(),
        "ref_qpos": qpos, "ref_qvel": qvel, "clip_steps": np.array(clip_steps), "clip_wraps": np.array(wrap),
    }  # fmt: skip


def reset_states(env: Any, f: Any) -> tuple[np.ndarray, np.ndarray]:
    """qpos [F, nq] and qvel [F, nv] of the character set onto each clip frame, through the engine's
    own setters (as `DeepMimicEnv._reset_char` sets them)."""
    e, c, env0 = env.engine, env.get_char_id(), torch.zeros(1, dtype=torch.long)
    m = e.mj_model
    qpos, qvel = np.empty((len(f.root_pos), m.nq)), np.empty((len(f.root_pos), m.nv))
    for i in range(len(f.root_pos)):
        row = slice(i, i + 1)
        e.set_root_state(env0, c, f.root_pos[row], f.root_rot[row], f.root_vel[row], f.root_ang_vel[row])
        e.set_joint_rot(env0, c, f.joint_rot[row])
        e.set_dof_vel(env0, c, f.dof_vel[row])
        state, _ = e.physics_state()  # time, qpos, qvel, ... (mjtState order)
        qpos[i], qvel[i] = state[0, 1 : 1 + m.nq], state[0, 1 + m.nq : 1 + m.nq + m.nv]
    return qpos, qvel
