"""Where the DoF velocity error of a tracking policy comes from (issue 35): the paper's DoF velocity
error of a deterministic rollout, split three ways.

1. As `mimickit test` reports it: the simulator's joint velocities (MuJoCo's qvel at the control step)
   against the clip's.
2. The same with the simulator's velocities replaced by the finite difference of its joint rotations over
   one control step (1/30 s): what the joints actually travelled. If 2 is much smaller than 1, most of
   the error is motion inside a control step (PD oscillation) that the poses never show.
3. The spectrum of the error signal over an episode: the share of its power above `--cutoff_hz`.

Also the clip against itself: its stored velocities against the finite difference of its own rotations
at the control step (what a perfect tracker would score against the clip's velocities).

    python benchmarks/dof_vel_gap.py --arg_file data/models/deepmimic_humanoid_walk_model.txt \
        --model_file data/models/deepmimic_humanoid_walk_model.pt --data_dir ../shared/data
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from mimickit.runner.policy import load_policy, policy_inputs
from mimickit.util.paths import DataPaths


def per_joint_error(dvel: torch.Tensor, dof_joint_ids: torch.Tensor, num_joints: int) -> torch.Tensor:
    """The paper's DoF term without the root: Σ_j ‖Δq̇_j‖ / J for DoF velocity differences [..., D]."""
    sq = dvel.square()
    per_joint = sq.new_zeros(*sq.shape[:-1], num_joints - 1).index_add_(-1, dof_joint_ids, sq).sqrt()
    return per_joint.sum(-1) / num_joints


def rollout(env, agent, steps: int) -> dict[str, torch.Tensor]:
    """Per step [T, N, ...]: sim and reference dof_vel and joint_rot, and whether the env was reset."""
    obs, _ = env.reset()
    keys = ("dof_vel", "joint_rot")
    out: dict[str, list[torch.Tensor]] = {f"{w}_{k}": [] for w in ("sim", "ref") for k in keys}
    out["done"] = []
    for _ in range(steps):
        obs, _, done, _ = env.step(agent.compute_action(obs, deterministic=True))
        sim, ref = env.get_char_state(), env.get_ref_state()
        for k in keys:
            out[f"sim_{k}"].append(sim[k].clone())
            out[f"ref_{k}"].append(ref[k].clone())
        out["done"].append(done.clone() != 0)
    return {k: torch.stack(v) for k, v in out.items()}


def high_share(err: np.ndarray, dt: float, cutoff_hz: float) -> float:
    """Share of the power of error signals [T, ...] (over time, mean removed) above `cutoff_hz`."""
    spec = np.abs(np.fft.rfft(err - err.mean(0), axis=0)) ** 2
    freqs = np.fft.rfftfreq(err.shape[0], dt)
    return float(spec[freqs > cutoff_hz].sum() / max(spec.sum(), 1e-12))


def parse_args() -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--arg_file", required=True)
    p.add_argument("--model_file", required=True)
    p.add_argument("--data_dir", default=None)
    p.add_argument("--num_envs", type=int, default=16)
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--cutoff_hz", type=float, default=5.0)
    return p.parse_args()


def report_split(sim_v, ref_v, sim_fd, ref_fd, ok, ids, J: int) -> None:
    """The error of each pairing of simulated and clip velocities (instantaneous or finite differences)."""

    def mean(x: torch.Tensor) -> float:
        return float(x[ok.squeeze(-1)].mean())

    rows = {
        "sim qvel vs clip vel (as mimickit test)": mean(per_joint_error(sim_v - ref_v, ids, J)),
        "sim finite diff vs clip vel": mean(per_joint_error(sim_fd - ref_v, ids, J)),
        "sim finite diff vs clip finite diff": mean(per_joint_error(sim_fd - ref_fd, ids, J)),
        "clip finite diff vs clip vel (a perfect tracker)": mean(per_joint_error(ref_fd - ref_v, ids, J)),
        "sim qvel vs sim finite diff (inside a step)": mean(per_joint_error(sim_v - sim_fd, ids, J)),
    }
    print("DoF part of the paper's DoF velocity error (rad/s, mean over steps; the root term left out):")
    for name, v in rows.items():
        print(f"  {name:52s} {v:.3f}")


def report_where(sim_v, ref_v, ref_fd, ok, ids, J: int, names: list[str]) -> None:
    """Which DoFs carry the error, whether a lag explains it, and how fast the clip's DoFs move."""
    for label, diff in (("sim vs clip", sim_v - ref_v), ("clip finite diff vs clip vel", ref_fd - ref_v)):
        worst = diff.abs()[ok.expand_as(diff)].view(-1, diff.shape[-1]).mean(0)
        top = torch.argsort(worst, descending=True)[:5]
        listed = ", ".join(f"{names[int(ids[i])]}[{int(i)}] {float(worst[i]):.2f}" for i in top)
        print(f"largest per-DoF mean |error|, {label} (rad/s): {listed}")
    print("the DoF error with the simulation shifted k control steps against the clip (a lag: a minimum at k > 0):")
    for k in range(-2, 5):
        a_, b_ = (sim_v[k:], ref_v[: len(ref_v) - k]) if k >= 0 else (sim_v[:k], ref_v[-k:])
        mask = ok[k:] & ok[: len(ok) - k] if k >= 0 else ok[:k] & ok[-k:]
        print(f"  k = {k:+d}: {float(per_joint_error(a_ - b_, ids, J)[mask.squeeze(-1)].mean()):.3f}")
    speed = ref_v.abs()[ok.expand_as(ref_v)].view(-1, ref_v.shape[-1]).mean(0)
    top = torch.argsort(speed, descending=True)[:4]
    listed = ", ".join(f"{names[int(ids[i])]}[{int(i)}] {float(speed[i]):.2f}" for i in top)
    print(f"the clip's mean |DoF velocity| (rad/s): {float(speed.mean()):.2f}; largest: {listed}")


def main() -> None:
    a = parse_args()
    paths = DataPaths(a.data_dir) if a.data_dir else DataPaths()
    env, agent = load_policy(policy_inputs(a.arg_file, paths), a.model_file, num_envs=a.num_envs)
    torch.manual_seed(0)
    with torch.no_grad():
        r = rollout(env, agent, a.steps)
    char, dt = env.char_model, env.engine.get_timestep()
    ids = torch.as_tensor(char.dof_joint_ids())
    J = ids.max().item() + 2  # non-root joints + the root
    # Steps t whose state follows step t-1 of the same episode (no reset in between).
    ok = ~(r["done"][1:] | r["done"][:-1]).unsqueeze(-1)
    sim_fd = char.compute_dof_vel(r["sim_joint_rot"][:-1], r["sim_joint_rot"][1:], dt)
    ref_fd = char.compute_dof_vel(r["ref_joint_rot"][:-1], r["ref_joint_rot"][1:], dt)
    sim_v, ref_v = r["sim_dof_vel"][1:], r["ref_dof_vel"][1:]
    print(f"{a.model_file}: {a.num_envs} envs x {a.steps} steps, control dt {dt:.4f} s, J = {J}")
    report_split(sim_v, ref_v, sim_fd, ref_fd, ok, ids, J)
    err = (sim_v - ref_v).numpy()
    print(f"share of the error's power above {a.cutoff_hz:g} Hz: {high_share(err, dt, a.cutoff_hz):.2f}")
    report_where(sim_v, ref_v, ref_fd, ok, ids, J, [j.name for j in char.joints[1:]])


if __name__ == "__main__":
    main()
