"""A stand-in for `mimickit train` that keeps its contract, for testing the studio's run manager.

    fake_trainer.py --arg_file F --out_dir D [--num_envs N] [--max_samples M] [--motion_file C]
                    [--data_dir X] [--model_file D/model.pt]

Like the real trainer it writes `D/metrics.jsonl` (one JSON object per iteration, flushed per line),
`D/log.txt` and `D/model.pt` (atomically, after every iteration), saves a checkpoint and exits 0 on
SIGTERM, and resumes its iteration count from `--model_file`. Its own keys in the arg file:
`--fake_rows R` (iterations before exiting, default 10), `--fake_period S` (seconds per iteration,
default 0.2) and `--fake_exit_code C` (exit code after the last row, default 0).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import tempfile
import time
from pathlib import Path


def read_arg_file(path: str) -> dict[str, str]:
    table: dict[str, str] = {}
    lines = [line for line in Path(path).read_text().splitlines() if not line.strip().startswith("#")]
    tokens = [t for line in lines for t in line.split()]
    for key, value in zip(tokens, [*tokens[1:], ""], strict=True):
        if key.startswith("--"):
            table[key[2:]] = value
    return table


def save_checkpoint(out_dir: Path, state: dict) -> None:
    """model.pt written the way the real trainer does: a temporary file renamed over the old one."""
    fd, tmp = tempfile.mkstemp(prefix=".model.pt.", dir=out_dir)
    with os.fdopen(fd, "w") as f:
        json.dump(state, f)
    os.replace(tmp, out_dir / "model.pt")


def main() -> int:
    p = argparse.ArgumentParser()
    for key in ("arg_file", "out_dir", "num_envs", "max_samples", "motion_file", "data_dir", "model_file"):
        p.add_argument(f"--{key}")
    args = p.parse_args()
    conf = read_arg_file(args.arg_file)
    rows, period = int(conf.get("fake_rows", 10)), float(conf.get("fake_period", 0.2))
    out_dir = Path(args.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    state = {"iteration": 0, "samples": 0}
    if args.model_file:
        state = json.loads(Path(args.model_file).read_text())
    num_envs = int(args.num_envs or 4)

    def on_term(signum: int, frame: object) -> None:
        save_checkpoint(out_dir, state)
        print(f"SIGTERM: checkpoint at iteration {state['iteration']}", flush=True)
        sys.exit(0)

    signal.signal(signal.SIGTERM, on_term)
    print(f"fake trainer: {vars(args)}", flush=True)
    start = time.time()
    with open(out_dir / "metrics.jsonl", "a") as metrics, open(out_dir / "log.txt", "a") as log:
        while state["iteration"] < rows:
            time.sleep(period)
            state["iteration"] += 1
            state["samples"] += num_envs * 32
            it = state["iteration"]
            row = {
                "iteration": it,
                "samples": state["samples"],
                "wall_time": time.time() - start,
                "train_return": 10.0 * it,
                "test_return": 9.0 * it,
                "train_episode_length": 20.0 + it,
                "test_episode_length": 19.0 + it,
                "actor_loss": 1.0 / it,
                "critic_loss": 2.0 / it,
                "reward_terms.pose": 0.5 + 0.01 * it,
                "reward_terms.vel": 0.2 + 0.01 * it,
            }
            metrics.write(json.dumps(row) + "\n")
            metrics.flush()
            log.write(f"iteration {it} samples {state['samples']}\n")
            log.flush()
            save_checkpoint(out_dir, state)
    return int(conf.get("fake_exit_code", 0))


if __name__ == "__main__":
    sys.exit(main())
