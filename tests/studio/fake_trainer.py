"""A stand-in for `mimickit train` that keeps its contract in a fraction of a second, for testing the
studio's run manager (queue, stop, kill -9, resume, the event stream). Every flow it stands in for
is also run with the real trainer in test_launch_fields.py / test_real_run.py.

    fake_trainer.py --arg_file F --out_dir D [--num_envs N] [--max_samples M] [--motion_file C]
                    [--rand_seed S] [--data_dir X] [--model_file D/model.pt]

It reads its arguments with MimicKit's own parser and runs the real trainer's checks on them
(`mimickit.runner.args.check_run_args`), so it refuses what the real trainer refuses (an unknown key,
a bad value: exit 2, one `error: ...` line) and accepts only its own three keys beyond. Like the real
trainer it writes,
through `mimickit.learning.run_folder`, `args.json` (argv, effective values, seed), `state.json` (running, then
finished / stopped / failed), `metrics.jsonl` (one row per iteration, flushed per line; a
`{"event": "resume"}` row when resumed), `log.txt` and `model.pt` (atomically, after every iteration);
it saves a checkpoint and exits 0 on SIGTERM, and resumes its counts from `--model_file`. Its own keys
in the arg file: `--fake_rows R` (iterations before it ends, default 10), `--fake_period S` (seconds
per iteration, default 0.2) and `--fake_exit_code C` (fail with this exit code after the last row).
"""

from __future__ import annotations

import json
import random
import signal
import sys
import time
from pathlib import Path

from mimickit.learning.run_folder import EndState, ExitCode, RunFolder, resume_row
from mimickit.runner.args import check_run_args
from mimickit.util.arg_parser import ArgParser
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import atomic_write_bytes

FAKE_KEYS = {"fake_rows", "fake_period", "fake_exit_code"}
SAMPLES_PER_ENV = 32
NO_LIMIT = 2**62


def parse(argv: list[str]) -> ArgParser:
    """All arguments; those that are not the stand-in's own go through the real trainer's checks.
    `--model_file` is the exception: the real check reads it as a torch checkpoint, and the stand-in's
    model.pt is a JSON counter, so only its existence is checked here."""
    args = ArgParser()
    args.load_args(argv)
    real = ArgParser()
    for key in args.all_keys():
        if key not in FAKE_KEYS and key != "model_file":
            real.set(key, *args.parse_strings(key))
    check_run_args(real)
    model_file = args.parse_string("model_file")
    if args.has_key("model_file") and not Path(model_file).is_file():
        raise MimicKitError(f"--model_file: file not found: {model_file}")
    return args


def main() -> int:
    try:
        args = parse(sys.argv[1:])
        rows, period = args.parse_int("fake_rows", 10), args.parse_float("fake_period", 0.2)
        num_envs = args.parse_int("num_envs", 4)
        max_samples = args.parse_int("max_samples", NO_LIMIT)
        seed = args.parse_int("rand_seed", -1)
    except MimicKitError as e:
        print(f"error: {e}", file=sys.stderr)
        return ExitCode.REFUSED
    seed = seed if seed >= 0 else random.randrange(2**31)
    folder = RunFolder(args.parse_string("out_dir"))
    folder.path.mkdir(parents=True, exist_ok=True)
    model_file = args.parse_string("model_file")
    state = json.loads(Path(model_file).read_text()) if model_file else {"iteration": 0, "samples": 0}
    effective = {
        "num_envs": num_envs,
        "max_samples": max_samples if max_samples < NO_LIMIT else None,
        "motion_file": args.parse_string("motion_file") or None,
    }
    previous = (folder.read_args() or {}) if model_file else None  # kept as the real trainer keeps it
    starts = [*previous.pop("previous_starts", []), previous] if previous is not None else []
    folder.write_args({"argv": sys.argv[1:], "effective": effective, "seed": seed, "previous_starts": starts})
    folder.write_state(EndState.RUNNING, iteration=state["iteration"], samples=state["samples"])

    def end(end_state: EndState, reason: str = "") -> None:
        save_checkpoint(folder, state)
        folder.write_state(end_state, reason, iteration=state["iteration"], samples=state["samples"])

    def on_term(signum: int, frame: object) -> None:
        end(EndState.STOPPED, "stopped by SIGTERM")
        print(f"SIGTERM: checkpoint at iteration {state['iteration']}", flush=True)
        sys.exit(0)

    signal.signal(signal.SIGTERM, on_term)
    print(f"fake trainer: {sys.argv[1:]}", flush=True)
    train(folder, state, rows, period, num_envs, max_samples, resumed=bool(model_file))
    code = args.parse_int("fake_exit_code", 0)
    if code:
        end(EndState.FAILED, f"fake failure with exit code {code}")
        print(f"error: fake failure with exit code {code}", file=sys.stderr, flush=True)
        return code
    end(EndState.FINISHED)
    return ExitCode.OK


def train(
    folder: RunFolder, state: dict, rows: int, period: float, num_envs: int, max_samples: int, resumed: bool
) -> None:
    start = time.time()
    with folder.metrics_file.open("a") as metrics, folder.log_file.open("a") as log:
        if resumed:
            marker = resume_row(state["iteration"], state["samples"], 0.0, max_samples)
            metrics.write(json.dumps(marker) + "\n")
        while state["iteration"] < rows and state["samples"] < max_samples:
            time.sleep(period)
            state["iteration"] += 1
            state["samples"] += num_envs * SAMPLES_PER_ENV
            it = state["iteration"]
            row = {
                "iteration": it,
                "samples": state["samples"],
                "wall_time": (time.time() - start) / 3600.0,
                "train_return": 10.0 * it,
                "test_return": 9.0 * it,
                "train_episode_length": 20.0 + it,
                "test_episode_length": 19.0 + it,
                "test_fail_frac": max(0.0, 1.0 - 0.01 * it),
                "tracking.paper_pos_err_m": 0.2 / (1.0 + 0.05 * it),
                "tracking.paper_dof_vel_err": 2.0 / (1.0 + 0.05 * it),
                "actor_loss": 1.0 / it,
                "critic_loss": 2.0 / it,
                "reward_terms.pose": 0.5 + 0.01 * it,
                "reward_terms.vel": 0.2 + 0.01 * it,
            }
            metrics.write(json.dumps(row) + "\n")
            metrics.flush()
            log.write(f"iteration {it} samples {state['samples']}\n")
            log.flush()
            save_checkpoint(folder, state)


def save_checkpoint(folder: RunFolder, state: dict) -> None:
    """model.pt written the way the real trainer does: whole or not at all."""
    atomic_write_bytes(folder.model_file, json.dumps(state).encode())


if __name__ == "__main__":
    sys.exit(main())
