"""Print how long hostile yaml configs take to be refused: in process (`load_yaml`, `load_env_configs`,
median of `--repeat` calls) and through `mimickit train` (a fresh process: wall time includes
Python's and torch's start-up, given beside a plain `--num_env` typo refused the same way).

    python benchmarks/yaml_bomb_refusal.py [--repeat 20]

Cases: the issue's billion laughs (10 levels of 10: 10^9 strings once expanded) as `episode_length`,
9^7, a recursive alias, and the largest bomb under the node limit (refused by pydantic with a
bounded echo, so the time to format the error is in it too).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mimickit.envs.env_builder import load_env_configs  # noqa: E402
from mimickit.util.config import load_yaml  # noqa: E402
from mimickit.util.errors import MimicKitError  # noqa: E402
from mimickit.util.paths import PROJECT_DATA_DIR, PROJECT_ROOT  # noqa: E402

ENGINE = PROJECT_DATA_DIR / "engines" / "mujoco_engine.yaml"
ARG_FILE = PROJECT_ROOT / "args" / "deepmimic_humanoid_ppo_args.txt"


def bomb(levels: int, width: int) -> str:
    lines = [f"_l0: &l0 [{', '.join(['lol'] * width)}]"]
    lines += [f"_l{i}: &l{i} [{', '.join([f'*l{i - 1}'] * width)}]" for i in range(1, levels)]
    return "env_name: deepmimic\n" + "\n".join(lines) + f"\nepisode_length: *l{levels - 1}\n"


CASES = {
    "billion laughs 10^9": bomb(9, 10),
    "bomb 9^7": bomb(7, 9),
    "recursive alias": "env_name: deepmimic\na: &a [1, *a]\nepisode_length: *a\n",
    "under the limit 9^5": bomb(5, 9),
}


def time_refusal(fn, path: Path, repeat: int) -> tuple[float, str]:
    times, msg = [], ""
    for _ in range(repeat):
        t = time.perf_counter()
        try:
            fn(path)
        except MimicKitError as e:
            msg = str(e)
        times.append(time.perf_counter() - t)
    return statistics.median(times), msg


def cli_seconds(argv: list[str]) -> tuple[float, int, str]:
    env = {**os.environ, "PYTHONPATH": str(PROJECT_ROOT)}
    t = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "mimickit.cli", "train", *argv], capture_output=True, text=True, env=env
    )
    return time.perf_counter() - t, proc.returncode, proc.stderr.strip()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeat", type=int, default=20)
    opts = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for name, text in CASES.items():
            path = Path(tmp) / "env.yaml"
            path.write_text(text)
            t_yaml, _ = time_refusal(load_yaml, path, opts.repeat)
            t_env, msg = time_refusal(lambda p: load_env_configs(p, ENGINE), path, opts.repeat)
            print(f"{name:22s} {len(text):5d} B  load_yaml {t_yaml * 1e3:7.2f} ms  load_env_configs "
                  f"{t_env * 1e3:7.2f} ms  error {len(msg)} chars")  # fmt: skip
        path = Path(tmp) / "env.yaml"
        path.write_text(CASES["billion laughs 10^9"])
        out = str(Path(tmp) / "run")
        for label, argv in (
            (
                "mimickit train, billion laughs",
                ["--arg_file", str(ARG_FILE), "--env_config", str(path), "--out_dir", out],
            ),
            ("mimickit train, --num_env typo", ["--arg_file", str(ARG_FILE), "--num_env", "8", "--out_dir", out]),
        ):
            secs, rc, err = cli_seconds(argv)
            print(f"{label:32s} {secs:5.2f} s  exit {rc}  {err[:100]}")


if __name__ == "__main__":
    main()
