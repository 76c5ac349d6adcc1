"""The same small 2-process training launched both ways, `--devices cpu cpu` (run.py spawns rank 1)
and `torchrun --standalone --nproc-per-node 2` (torchrun starts both), with one seed:

    python benchmarks/torchrun_vs_devices.py --num_envs 4 --iters 2 --repeats 2

Prints one JSON object: per launcher, the median wall time of the whole command (interpreter start
to exit), end-to-end samples/s (samples / that wall time) and the trainer's own samples/s (the
median over runs of metrics.jsonl's mean `time.samples_per_s`); and whether every metrics row other
than its timings was equal between the two launchers in every repeat.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TORCHRUN = str(Path(sys.executable).with_name("torchrun"))


def _rows(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]


def _untimed(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k not in ("time", "wall_time") and not k.startswith("time.")} for r in rows]


def _launch(launcher: str, train: list[str]) -> list[str]:
    if launcher == "torchrun":
        return [TORCHRUN, "--standalone", "--nproc-per-node", "2", "-m", "mimickit.cli", *train]
    return [sys.executable, "-m", "mimickit.cli", *train, "--devices", "cpu", "cpu"]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--arg_file", default="args/deepmimic_humanoid_demo_ppo_args.txt")
    p.add_argument("--num_envs", type=int, default=4)
    p.add_argument("--iters", type=int, default=2)
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--seed", type=int, default=7)
    a = p.parse_args()
    samples = 2 * a.num_envs * 32 * a.iters  # 32 steps per iteration (the demo agent's steps_per_iter)
    stats: dict[str, dict[str, list[float]]] = {k: {"wall": [], "sps": []} for k in ("devices", "torchrun")}
    equal = True
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(a.repeats):
            rows = {}
            for launcher in ("devices", "torchrun") if i % 2 == 0 else ("torchrun", "devices"):
                out = Path(tmp) / f"{launcher}{i}"
                train = ["train", "--arg_file", a.arg_file, "--num_envs", str(a.num_envs), "--out_dir", str(out),
                         "--max_samples", str(samples), "--rand_seed", str(a.seed)]  # fmt: skip
                t0 = time.perf_counter()
                subprocess.run(_launch(launcher, train), cwd=ROOT, check=True, capture_output=True, timeout=900)
                stats[launcher]["wall"].append(time.perf_counter() - t0)
                rows[launcher] = _rows(out)
                stats[launcher]["sps"].append(statistics.mean(r["time.samples_per_s"] for r in rows[launcher]))
            equal = equal and _untimed(rows["devices"]) == _untimed(rows["torchrun"])
    report = {"num_envs_per_proc": a.num_envs, "iters": a.iters, "samples": samples, "seed": a.seed,
              "repeats": a.repeats, "metrics_rows_equal": equal}  # fmt: skip
    for launcher, s in stats.items():
        wall = statistics.median(s["wall"])
        report[launcher] = {
            "wall_s": round(wall, 2),
            "end_to_end_samples_per_s": round(samples / wall, 1),
            "trainer_samples_per_s": round(statistics.median(s["sps"]), 1),
        }
    print(json.dumps(report))


if __name__ == "__main__":
    main()
