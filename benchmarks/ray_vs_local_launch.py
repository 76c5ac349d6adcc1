"""Launch-to-first-metrics-row time of a studio run, local executor vs Ray executor, and a 4-run sweep's
timeline on a 2-CPU Ray head (1 CPU per run), all with the real trainer on the demo config:

    python benchmarks/ray_vs_local_launch.py --repeats 2

Starts a local Ray head (2 CPUs, its own temp dir) and, per executor, a studio on a fresh runs folder;
each repeat POSTs a run (`--num_envs 4`) and times, from the POST, when the API first lists the run
`running` and when its first training row is in metrics.jsonl; the run is then stopped. The sweep
(`rand_seed=0..3`, `--max_samples` of 2 iterations each) reports each run's start and end (the
registry's times, seconds after the sweep was posted) and the most runs that were going at once.
Prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mimickit.learning.run_folder import is_event_row  # noqa: E402
from tests.studio.conftest import REAL_TRAINER, StudioProcess, wait_for  # noqa: E402
from tests.studio.ray_head import local_ray_head  # noqa: E402

DEMO_ARGS = "args/deepmimic_humanoid_demo_ppo_args.txt"
PER_ITER = 4 * 32
TIMEOUT_S = 600.0


def studio_for(executor: str, ray_url: str, runs_dir: Path) -> StudioProcess:
    extra = ("--executor", executor, "--ray-address", ray_url, "--clip", "none")
    runs_dir.mkdir(parents=True)
    return StudioProcess(runs_dir, None, *extra, trainer=REAL_TRAINER)


def first_row_times(studio: StudioProcess) -> dict[str, float]:
    """Seconds from the POST to `running` and to the first training row."""
    body = {"arg_file": DEMO_ARGS, "num_envs": 4, "max_samples": 1000 * PER_ITER, "num_cpus": 1}
    t0 = time.monotonic()
    run_id = studio.post("/api/runs", body).json()["id"]
    running = first_row = None
    while first_row is None and time.monotonic() - t0 < TIMEOUT_S:
        if running is None and studio.get(f"/api/runs/{run_id}").json()["status"] == "running":
            running = time.monotonic() - t0
        rows = studio.get(f"/api/runs/{run_id}/metrics", params={"follow": "false"}).json()
        if any(not is_event_row(r) for r in rows):
            first_row = time.monotonic() - t0
        time.sleep(0.1)
    studio.post(f"/api/runs/{run_id}/stop")
    wait_for(lambda: studio.get(f"/api/runs/{run_id}").json()["status"] not in ("running", "stopping"), TIMEOUT_S)
    return {"to_running_s": round(running or float("nan"), 2), "to_first_row_s": round(first_row or float("nan"), 2)}


def sweep_timeline(studio: StudioProcess) -> dict[str, object]:
    body = {"arg_file": DEMO_ARGS, "values": {"rand_seed": [0, 1, 2, 3]}, "num_envs": 4}
    body |= {"max_samples": 2 * PER_ITER, "num_cpus": 1, "name": "timeline"}
    posted = time.time()
    sweep = studio.post("/api/sweeps", body).json()
    ids = [r["id"] for r in sweep["runs"]]

    def ended() -> list[dict] | None:
        runs = [studio.get(f"/api/runs/{i}").json() for i in ids]
        return runs if all(r["status"] not in ("queued", "running", "stopping") for r in runs) else None

    runs = wait_for(ended, TIMEOUT_S, "the sweep to end")
    spans = [(r["started_at"] - posted, r["ended_at"] - posted) for r in runs]
    at_once = max(sum(s <= t < e for s, e in spans) for t, _ in spans)
    timeline = [
        {"run": r["id"], "seed": r["config"]["rand_seed"], "status": r["status"], "start_s": round(s, 1),
         "end_s": round(e, 1)}
        for r, (s, e) in zip(runs, spans, strict=True)
    ]  # fmt: skip
    return {"runs": timeline, "most_at_once": at_once}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--no-sweep", action="store_true")
    args = parser.parse_args()
    out: dict[str, object] = {}
    with local_ray_head(2) as ray_url, tempfile.TemporaryDirectory() as tmp:
        for executor in ("local", "ray"):
            studio = studio_for(executor, ray_url, Path(tmp) / executor)
            try:
                times = [first_row_times(studio) for _ in range(args.repeats)]
                if executor == "ray" and not args.no_sweep:
                    out["sweep"] = sweep_timeline(studio)
            finally:
                studio.stop()
            out[executor] = {
                "repeats": times,
                "median_to_first_row_s": statistics.median(t["to_first_row_s"] for t in times),
            }
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
