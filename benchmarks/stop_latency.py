"""How soon a stop takes effect, measured here instead of asserted in tests (the tests check that the
stop happened and why, by what happened, not by the clock):

- the guarded clip parser (`mimickit.util.guarded.run_guarded`): seconds from the time budget to the
  error, for a child that would sleep far past it;
- `mimickit train` on SIGTERM: seconds from the signal to the exit, and metrics rows written after it.

    python benchmarks/stop_latency.py [--repeats 3] [--budget 1.0]

One run, one machine: the figures move with the load (printed first): compare runs made together.
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from mimickit.util.errors import MimicKitError
from mimickit.util.guarded import run_guarded
from mimickit.util.paths import PROJECT_ROOT

ARG_FILE = PROJECT_ROOT / "args" / "deepmimic_humanoid_demo_ppo_args.txt"


def sleep_long() -> bytes:
    time.sleep(600)
    return b""


def guard_overrun(budget: float) -> float:
    """Seconds past `budget` until run_guarded gives up on a child that sleeps on."""
    t0 = time.perf_counter()
    try:
        run_guarded(sleep_long, label="slow.pkl", timeout_s=budget)
    except MimicKitError:
        return time.perf_counter() - t0 - budget
    raise SystemExit("run_guarded returned: the time budget did not stop the child")


def rows(metrics: Path) -> int:
    return metrics.read_text().count("\n") if metrics.is_file() else 0


def sigterm_stop(out: Path) -> tuple[float, int]:
    """Seconds from SIGTERM (sent once the first iteration is logged) to the trainer's exit, rows after it."""
    cmd = [sys.executable, "-m", "mimickit.cli", "train", "--arg_file", str(ARG_FILE), "--num_envs", "4"]
    proc = subprocess.Popen([*cmd, "--out_dir", str(out)], cwd=PROJECT_ROOT, stdout=subprocess.DEVNULL)
    try:
        while rows(out / "metrics.jsonl") == 0:
            if proc.poll() is not None:
                raise SystemExit(f"the trainer exited with {proc.returncode} before its first iteration")
            time.sleep(0.1)
        before = rows(out / "metrics.jsonl")
        proc.send_signal(signal.SIGTERM)
        t0 = time.perf_counter()
        code = proc.wait(600)
        seconds = time.perf_counter() - t0
    finally:
        proc.kill()
    if code != 0:
        raise SystemExit(f"the trainer exited with {code} after SIGTERM")
    return seconds, rows(out / "metrics.jsonl") - before


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--budget", type=float, default=1.0, help="run_guarded's timeout_s")
    args = ap.parse_args()
    print(f"load: {os.getloadavg()[0]:.2f} (1 min), {os.cpu_count()} CPUs")
    over = [guard_overrun(args.budget) for _ in range(args.repeats)]
    print(
        f"run_guarded, {args.budget:g} s budget: error {statistics.median(over) * 1e3:.0f} ms past it"
        f" (median of {args.repeats}, max {max(over) * 1e3:.0f} ms)"
    )
    with tempfile.TemporaryDirectory() as d:
        stops = [sigterm_stop(Path(d) / f"run{i}") for i in range(args.repeats)]
    secs = [s for s, _ in stops]
    print(
        f"mimickit train, SIGTERM after the first iteration: exit {statistics.median(secs):.2f} s later"
        f" (median of {args.repeats}, max {max(secs):.2f} s); rows written after it: {[n for _, n in stops]}"
    )


if __name__ == "__main__":
    main()
