"""Test every shipped policy in data/models over many episodes and print one markdown row each.

    python benchmarks/zoo_test.py --data_dir ../shared/data --episodes 256 --num_envs 4 32

Each policy runs `mimickit test` with its sidecar arg file once per --num_envs value, with the same seed;
a row adds the runs up: mean episode length, episodes that reached the end (the time limit, or the end of a
clip that does not loop: DeepMimic ends those episodes as a success there), the paper's errors.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

MODELS = Path(__file__).resolve().parents[1] / "data" / "models"


def test_once(name: str, num_envs: int, args: argparse.Namespace) -> dict:
    cmd = [
        sys.executable, "-m", "mimickit.cli", "test", "--arg_file", str(MODELS / f"{name}.txt"),
        "--model_file", str(MODELS / f"{name}.pt"), "--num_envs", str(num_envs),
        "--test_episodes", str(args.episodes), "--rand_seed", str(args.rand_seed), "--json",
    ]  # fmt: skip
    if args.data_dir:
        cmd += ["--data_dir", args.data_dir]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"{name}: mimickit test failed: {r.stderr.strip().splitlines()[-1]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def row(name: str, runs: list[dict]) -> str:
    episodes = sum(r["episodes"] for r in runs)
    full = sum(r["episode_ends"]["time"] + r["episode_ends"]["succ"] for r in runs)

    def mean(key: str, tracking: bool = True) -> float | None:
        """Episode-weighted mean; None when a run has no such figure (AMP has no clip to track)."""
        values = [((r["tracking"] if tracking else r).get(key), r["episodes"]) for r in runs]
        return None if any(v is None for v, _ in values) else sum(v * n for v, n in values) / episodes

    def fmt(value: float | None, spec: str) -> str:
        return "–" if value is None else format(value, spec)

    return (
        f"| `{name}` | {fmt(mean('mean_episode_length', tracking=False), '.1f')} | {full} of {episodes} | "
        f"{fmt(mean('paper_pos_err_m'), '.3f')} | {fmt(mean('paper_dof_vel_err'), '.2f')} |"
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data_dir", help="MimicKit's data folder (the policies trained on its clips need it)")
    p.add_argument("--episodes", type=int, default=256, help="test episodes per run")
    p.add_argument("--num_envs", type=int, nargs="+", default=[4, 32], help="one run per value")
    p.add_argument("--rand_seed", type=int, default=0)
    p.add_argument("--models", nargs="*", help="names without .pt (default: every model in data/models)")
    args = p.parse_args()
    names = args.models or sorted(m.stem for m in MODELS.glob("*_model.pt"))
    ends = "to the end (time limit or clip's end)"
    print(f"| policy | mean episode length | {ends} | paper_pos_err_m | paper_dof_vel_err |")
    print("|---|---|---|---|---|")
    for name in names:
        print(row(name, [test_once(name, n, args) for n in args.num_envs]), flush=True)


if __name__ == "__main__":
    main()
