"""`mimickit bench` of two source trees in one run, alternating, so a load that comes and goes on a shared
machine weighs on both alike (figures, not tests).

    git worktree add /tmp/old <rev>
    python benchmarks/revision_ab.py /tmp/old . [--rounds 3] -- --raw replay --num_envs 256 --steps 100

Each round runs `python -m mimickit.cli bench --json ARGS` once in each tree (a fresh process, that tree's
code first on sys.path; the order flips every round), then prints per round and over all rounds: each
tree's `ratio` (env step against raw MuJoCo re-running it, when the bench has one) and env steps/s, and
new/old of both; with `--train`, the training samples/s and `train_ratio` too.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any


def bench(tree: Path, bench_args: list[str]) -> dict[str, Any]:
    """One `mimickit bench --json` in `tree`, with this interpreter."""
    cmd = [sys.executable, "-m", "mimickit.cli", "bench", "--json", *bench_args]
    out = subprocess.run(cmd, cwd=tree, capture_output=True, text=True, check=False)
    if out.returncode != 0:
        raise SystemExit(f"{tree}: bench failed ({out.returncode}): {out.stderr.strip()[-400:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("old", type=Path)
    ap.add_argument("new", type=Path)
    ap.add_argument("--rounds", type=int, default=3)
    args, rest = ap.parse_known_args()
    bench_args = [a for a in rest if a != "--"]
    runs: dict[str, list[dict[str, Any]]] = {"old": [], "new": []}
    for r in range(args.rounds):
        order = ("old", "new") if r % 2 == 0 else ("new", "old")
        for name in order:
            runs[name].append(bench(getattr(args, name).resolve(), bench_args))
        old, new = runs["old"][-1], runs["new"][-1]
        print(f"round {r + 1}: " + _line(old, new), flush=True)
    old_sps = statistics.median(x["env_steps_per_s"] for x in runs["old"])
    new_sps = statistics.median(x["env_steps_per_s"] for x in runs["new"])
    summary: dict[str, Any] = {"env_steps_per_s_old": old_sps, "env_steps_per_s_new": new_sps}
    summary["sps_new_over_old"] = round(new_sps / old_sps, 4)
    for key in ("train_samples_per_s", "ratio", "train_ratio"):  # `--train` prints the train_* figures
        if runs["old"][0].get(key) is None:
            continue
        summary[f"{key}_old"] = [x[key] for x in runs["old"]]
        summary[f"{key}_new"] = [x[key] for x in runs["new"]]
        summary[f"{key}_new_over_old"] = round(
            statistics.median(summary[f"{key}_new"]) / statistics.median(summary[f"{key}_old"]), 4
        )
    print(json.dumps(summary))


def _line(old: dict[str, Any], new: dict[str, Any]) -> str:
    text = f"env steps/s old {old['env_steps_per_s']:,.0f} new {new['env_steps_per_s']:,.0f}"
    for key in ("train_samples_per_s", "ratio", "train_ratio"):
        if old.get(key) is not None:
            text += f"; {key} old {old[key]:,.3f} new {new[key]:,.3f}"
    return text


if __name__ == "__main__":
    main()
