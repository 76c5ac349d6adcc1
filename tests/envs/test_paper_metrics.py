"""The paper's tracking errors (`paper_pos_err_m`, `paper_dof_vel_err`) beside the reference code's:
hand-derived values on hand-made states, the real DeepMimic env (MuJoCo humanoid), and a real
`mimickit test --json` / `mimickit train` run showing them in the `tracking` dict and metrics.jsonl."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from mimickit.envs.base_env import EnvMode
from mimickit.envs.deepmimic_rewards import tracking_errors
from mimickit.envs.env_builder import build_env
from mimickit.util import torch_util as tu
from mimickit.util.paths import PROJECT_DATA_DIR, PROJECT_ROOT

ENGINE = PROJECT_DATA_DIR / "engines/mujoco_engine.yaml"
DEEPMIMIC = PROJECT_DATA_DIR / "envs/deepmimic_humanoid_env.yaml"
# A hand-made character: root + joint 1 (ball, DoFs 0-2) + joint 2 (hinge, DoF 3): J = 3 = N_joint + 1.
DOF_JOINT_IDS = torch.tensor([0, 0, 0, 1])
J = 3


def state(root_pos=(0.0, 0.0, 1.0), body_offsets=None, rot=None, ang_vel=(0.0, 0.0, 0.0), dof_vel=None) -> dict:
    """One env's state [1, ...]: bodies at root + (0,0,-0.3·j) (+ body_offsets), all rotated `rot`."""
    root = torch.tensor([root_pos])
    rel = torch.tensor([[[0.0, 0.0, -0.3 * j] for j in range(J)]])
    if body_offsets is not None:
        rel = rel + torch.tensor([body_offsets])
    q = torch.tensor([rot if rot is not None else [0.0, 0.0, 0.0, 1.0]])
    return {
        "root_pos": root, "root_rot": q, "root_vel": torch.zeros(1, 3), "root_ang_vel": torch.tensor([ang_vel]),
        "body_pos": root.unsqueeze(1) + rel, "body_rot": q.unsqueeze(1).expand(1, J, 4),
        "dof_vel": torch.tensor([dof_vel if dof_vel is not None else [0.0] * 4]),
    }  # fmt: skip


def errors(sim: dict, ref: dict) -> dict[str, float]:
    return {k: float(v[0]) for k, v in tracking_errors(sim, ref, DOF_JOINT_IDS).items()}


def test_a_pure_root_offset_counts_once_in_the_paper_error_and_not_at_all_in_the_code_one():
    # Every body moved with the root by (0.3, 0.4, 0): |Δroot| = 0.5, no root-relative error.
    e = errors(state(root_pos=(0.3, 0.4, 1.0)), state())
    assert e["body_pos_err"] == pytest.approx(0.0, abs=1e-7)
    assert e["root_pos_err"] == pytest.approx(0.5, rel=1e-6)
    assert e["paper_pos_err_m"] == pytest.approx(0.5 / J, rel=1e-6)


def test_root_relative_errors_and_the_root_term_add_over_n_joint_plus_one():
    # Joint 2's body 0.2 m off (root-relative), root 0.5 m off: code = 0.2/3 (the root's own term is 0),
    # paper = (0 + 0.2 + 0.5)/3.
    offsets = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.2, 0.0]]
    e = errors(state(root_pos=(0.3, 0.4, 1.0), body_offsets=offsets), state())
    assert e["body_pos_err"] == pytest.approx(0.2 / J, rel=1e-6)
    assert e["paper_pos_err_m"] == pytest.approx(0.7 / J, rel=1e-6)


def test_dof_velocity_error_is_a_per_joint_l2_plus_the_local_root_term():
    # Ball joint Δ = (0.3, 0.4, 0) → 0.5; hinge Δ = −2 → 2. The root is turned 90° about z and spins
    # about world y, i.e. about its own x, as the reference spins about its (= world) x: no local error,
    # though the world-frame vectors differ by √2.
    yaw90 = tu.quat_from_axis_angle(torch.tensor([0.0, 0.0, 1.0]), torch.tensor(math.pi / 2)).tolist()
    sim = state(rot=yaw90, ang_vel=(0.0, 1.0, 0.0), dof_vel=[0.3, 0.4, 0.0, -2.0])
    e = errors(sim, state(ang_vel=(1.0, 0.0, 0.0)))
    assert e["paper_dof_vel_err"] == pytest.approx((0.5 + 2.0 + 0.0) / J, rel=1e-6)
    assert e["dof_vel_err"] == pytest.approx((0.3 + 0.4 + 0.0 + 2.0) / 4, rel=1e-6)  # the code's: mean |Δ| per DoF
    assert e["root_ang_vel_err"] == pytest.approx(2.0 / 3, rel=1e-6)  # world frame, mean over xyz

    # The same roots, one spinning about its z at 1 rad/s and the other still: the root term is 1.
    e = errors(state(ang_vel=(0.0, 0.0, 1.0)), state())
    assert e["paper_dof_vel_err"] == pytest.approx(1.0 / J, rel=1e-6)


def test_matching_states_have_zero_paper_errors():
    s = state(root_pos=(1.0, 2.0, 0.9), ang_vel=(0.1, 0.2, 0.3), dof_vel=[1.0, -1.0, 0.5, 2.0])
    e = errors(s, {k: v.clone() for k, v in s.items()})
    assert e["paper_pos_err_m"] == 0.0 and e["paper_dof_vel_err"] == 0.0


def test_real_env_reports_both_and_the_paper_position_error_adds_the_root_over_j():
    env = build_env(DEEPMIMIC, ENGINE, num_envs=4)
    env.set_mode(EnvMode.TEST)
    env.reset()
    _, _, _, info = env.step(torch.zeros(4, env.get_action_space().shape[0]))
    t = info["tracking"]
    assert {"paper_pos_err_m", "paper_dof_vel_err"} <= set(t)
    num_bodies = env.char_model.get_num_joints()  # 15 for the humanoid: 14 joints + the root
    torch.testing.assert_close(t["paper_pos_err_m"], t["body_pos_err"] + t["root_pos_err"] / num_bodies)
    assert bool((t["paper_dof_vel_err"] > 0).all()), "zero actions: the character drifts from the clip"
    summary = env.tracking_summary()
    assert summary["paper_pos_err_m"] == pytest.approx(
        summary["body_pos_err"] + summary["root_pos_err"] / num_bodies, rel=1e-5
    )


def mimickit(*args: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "mimickit.cli", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=PROJECT_ROOT)


@pytest.mark.integration
@pytest.mark.slow
def test_mimickit_test_json_and_metrics_jsonl_carry_the_paper_errors(tmp_path: Path):
    name = PROJECT_ROOT / "data/models/deepmimic_humanoid_demo_model"
    r = mimickit(
        "test", "--arg_file", f"{name}.txt", "--model_file", f"{name}.pt", "--num_envs", "2",
        "--test_episodes", "2", "--json",
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    tracking = json.loads(r.stdout.strip().splitlines()[-1])["tracking"]
    for key in ("paper_pos_err_m", "paper_dof_vel_err", "pos_err_m", "dof_vel_err"):
        assert key in tracking and tracking[key] > 0.0, (key, tracking)
    # Means over the same env-steps: the paper's error is the code's plus the root error over J = 15.
    assert tracking["paper_pos_err_m"] == pytest.approx(tracking["pos_err_m"] + tracking["root_pos_err"] / 15, rel=1e-4)

    out = tmp_path / "run"
    r = mimickit(
        "train", "--arg_file", str(PROJECT_ROOT / "args/deepmimic_humanoid_demo_ppo_args.txt"), "--num_envs", "4",
        "--out_dir", str(out), "--max_samples", "128",
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    rows = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert rows and all(row["tracking.paper_pos_err_m"] > 0 and row["tracking.paper_dof_vel_err"] > 0 for row in rows)
