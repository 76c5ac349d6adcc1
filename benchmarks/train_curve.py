"""A time-boxed `mimickit train` run and its learning curve.

Trains for `--minutes` of wall time (then SIGTERM: the trainer saves `model.pt` and exits), tests the
final checkpoint in a fresh process (`mimickit test --json`), and prints the curve (test return and
episode length against samples and wall time), the tracking error, and where an iteration's time goes
(simulation, policy inference, update) with the samples/s it reached. Everything printed is read back
from the run's own metrics.jsonl and the test's JSON.

    # the acceptance run of the walk policy (2 hours on this 2-core CPU)
    python benchmarks/train_curve.py --minutes 120 --out_dir output/walk_curve \\
        -- --arg_file args/deepmimic_humanoid_walk_ppo_args.txt --data_dir ../shared/data
    # end-to-end throughput of the default humanoid config (a few minutes)
    python benchmarks/train_curve.py --minutes 3 --out_dir output/throughput \\
        -- --arg_file args/deepmimic_humanoid_ppo_args.txt
    # the adversarial acceptance runs (1 hour each): a preset names the arg file and the columns to print
    python benchmarks/train_curve.py --preset amp_walk --minutes 60 --out_dir output/amp_walk_curve
    python benchmarks/train_curve.py --preset add_walk --minutes 60 --out_dir output/add_walk_curve
    python benchmarks/train_curve.py --preset location --minutes 60 --out_dir output/location_curve
    python benchmarks/train_curve.py --preset ase --minutes 60 --out_dir output/ase_curve
    # report an existing run without training
    python benchmarks/train_curve.py --report_only --out_dir output/walk_curve -- --arg_file ...
"""

from __future__ import annotations

import argparse
import json
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MIMICKIT = [sys.executable, "-m", "mimickit.cli"]

# The acceptance runs: arg file (all but demo need MimicKit's data, --data_dir) and the columns that show
# whether the method learns.
PRESETS: dict[str, tuple[str, list[str]]] = {
    "walk": ("deepmimic_humanoid_walk_ppo_args.txt", ["tracking.body_pos_err"]),
    "demo": ("deepmimic_humanoid_demo_ppo_args.txt", ["tracking.body_pos_err"]),
    "amp_walk": ("amp_humanoid_walk_args.txt", ["reward_terms.disc", "disc_agent_acc", "disc_demo_acc"]),
    "add_walk": (
        "add_humanoid_walk_args.txt",
        ["tracking.body_pos_err", "tracking.dof_vel_err", "reward_terms.disc", "disc_pos_acc", "disc_neg_acc"],
    ),
    "location": ("amp_location_humanoid_cpu_args.txt", ["tar_reached_frac", "tar_episodes", "reward_terms.task"]),
    "ase": ("ase_humanoid_cpu_args.txt", ["reward_terms.disc", "reward_terms.enc", "diversity_loss"]),
}


def train(out_dir: Path, minutes: float, train_args: list[str]) -> None:
    cmd = [*MIMICKIT, "train", *train_args, "--out_dir", str(out_dir)]
    print("$", " ".join(cmd), flush=True)
    out_dir.mkdir(parents=True, exist_ok=True)
    with open(out_dir / "console.log", "a") as log:
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)
        try:
            proc.wait(timeout=minutes * 60)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGTERM)  # graceful: the trainer saves model.pt and exits 0
            proc.wait()
    if proc.returncode != 0:
        raise SystemExit(f"train exited with {proc.returncode}; see {out_dir / 'console.log'}")


def test(out_dir: Path, train_args: list[str], episodes: int) -> dict:
    cmd = [*MIMICKIT, "test", *train_args, "--model_file", str(out_dir / "model.pt")]
    cmd += ["--test_episodes", str(episodes), "--json"]
    print("$", " ".join(cmd), flush=True)
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"test failed:\n{r.stderr[-3000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def curve_rows(rows: list[dict], shown: int) -> list[dict]:
    """Every tested iteration plus `shown` evenly spaced ones (training-side metrics move between tests)."""
    picked = {r["iteration"]: r for r in rows if r.get("output")}
    step = max(1, len(rows) // max(1, shown))
    picked.update({r["iteration"]: r for r in [*rows[::step], rows[-1]]})
    return [picked[i] for i in sorted(picked)]


def fmt(value: float | None, width: int) -> str:
    if value is None:
        return f"{'-':>{width}}"
    if isinstance(value, int):
        return f"{value:>{width}d}"
    return f"{value:>{width}.0f}" if abs(value) >= 1e4 else f"{value:>{width}.3f}"


def report(out_dir: Path, result: dict | None, rows_shown: int, columns: list[str]) -> None:
    rows = [json.loads(line) for line in (out_dir / "metrics.jsonl").read_text().splitlines()]
    print(f"\ncurve of {out_dir} ({len(rows)} iterations; wall_time in hours; test_* only on tested iterations):")
    keys = ["samples", "wall_time", "test_return", "test_episode_length", "train_episode_length", *columns]
    widths = [max(9, len(k)) for k in keys]
    print(f"{'iter':>6}", " ".join(f"{k:>{w}}" for k, w in zip(keys, widths, strict=True)))
    for r in curve_rows(rows, rows_shown):
        cells = [
            fmt(r.get(k) if r.get("output") or not k.startswith("test_") else None, w)
            for k, w in zip(keys, widths, strict=True)
        ]
        print(f"{r['iteration']:>6}", " ".join(cells))
    timed = [r for r in rows if "time.samples_per_s" in r][1:]  # the first iteration warms up
    if timed:
        parts = {k: statistics.fmean(r[f"time.{k}_s"] for r in timed) for k in ("sim", "inference", "update")}
        total = sum(parts.values())
        split = ", ".join(f"{k} {v / total:.0%} ({v:.2f} s)" for k, v in parts.items())
        rate = statistics.fmean(r["time.samples_per_s"] for r in timed)
        print(f"\nthroughput: {rate:.0f} samples/s over {len(timed)} iterations; per iteration: {split}")
    if result is not None:
        print("\nfinal test (fresh process):", json.dumps(result))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, default=120.0, help="wall-time budget of the training run")
    parser.add_argument("--out_dir", type=Path, required=True)
    parser.add_argument("--test_episodes", type=int, default=32)
    parser.add_argument("--rows", type=int, default=20, help="evenly spaced curve rows (plus every tested one)")
    parser.add_argument(
        "--columns",
        nargs="*",
        default=["tracking.body_pos_err"],
        metavar="KEY",
        help="more metrics.jsonl keys to print (e.g. reward_terms.disc disc_agent_acc tar_reached_frac)",
    )
    parser.add_argument("--report_only", action="store_true", help="report an existing run")
    parser.add_argument("--preset", choices=sorted(PRESETS), help="an acceptance run: its arg file and columns")
    parser.add_argument("--data_dir", default="../shared/data", help="MimicKit's data folder (with --preset)")
    parser.add_argument("train_args", nargs=argparse.REMAINDER, help="-- then the `mimickit train` arguments")
    args = parser.parse_args()
    train_args = [a for a in args.train_args if a != "--"]
    if args.preset:
        arg_file, columns = PRESETS[args.preset]
        train_args = ["--arg_file", f"args/{arg_file}", "--data_dir", args.data_dir, *train_args]
        args.columns = [*columns, *(c for c in args.columns if c not in columns)]
    out_dir = args.out_dir.resolve()
    start = time.monotonic()
    if not args.report_only:
        train(out_dir, args.minutes, train_args)
        print(f"trained for {(time.monotonic() - start) / 60:.1f} min", flush=True)
    result = test(out_dir, train_args, args.test_episodes) if args.test_episodes > 0 else None
    report(out_dir, result, args.rows, args.columns)


if __name__ == "__main__":
    main()
