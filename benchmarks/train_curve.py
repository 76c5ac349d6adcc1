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


def report(out_dir: Path, result: dict | None, rows_shown: int) -> None:
    rows = [json.loads(line) for line in (out_dir / "metrics.jsonl").read_text().splitlines()]
    tested = [r for r in rows if r.get("output")]
    step = max(1, len(tested) // rows_shown)
    print(f"\ncurve of {out_dir} ({len(rows)} iterations; test rows every iters_per_output):")
    head = ("iter", 6), ("samples", 10), ("hours", 6), ("test_ret", 9), ("test_len", 9), ("train_len", 9)
    print(" ".join(f"{name:>{width}}" for name, width in head), f"{'body_err_m':>10}")
    for r in [*tested[::step], *([tested[-1]] if tested and (len(tested) - 1) % step else [])]:
        print(
            f"{r['iteration']:>6} {r['samples']:>10} {r['wall_time']:>6.2f} {r['test_return']:>9.2f}"
            f" {r['test_episode_length']:>9.1f} {r['train_episode_length']:>9.1f}"
            f" {r.get('tracking.body_pos_err', float('nan')):>10.3f}"
        )
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
    parser.add_argument("--rows", type=int, default=20, help="curve rows to print")
    parser.add_argument("--report_only", action="store_true", help="report an existing run")
    parser.add_argument("train_args", nargs=argparse.REMAINDER, help="-- then the `mimickit train` arguments")
    args = parser.parse_args()
    train_args = [a for a in args.train_args if a != "--"]
    out_dir = args.out_dir.resolve()
    start = time.monotonic()
    if not args.report_only:
        train(out_dir, args.minutes, train_args)
        print(f"trained for {(time.monotonic() - start) / 60:.1f} min", flush=True)
    result = test(out_dir, train_args, args.test_episodes) if args.test_episodes > 0 else None
    report(out_dir, result, args.rows)


if __name__ == "__main__":
    main()
