"""How the studio's run list and queue hold up with many runs: a registry of `--ended` ended runs (each with
a run folder as a trainer leaves it: args.json, env_config.yaml, metrics.jsonl, state.json, model.pt) and
`--queued` queued runs, written straight into `<runs-dir>/registry.sqlite`, then a real
`mimickit-studio serve` on it (its trainer sleeps, so one run holds the one slot and the rest wait).

Prints: `GET /api/runs` (the first, the median of 5 more back to back and of 5 spaced past the list's
0.5 s cache), the first `runs` event of `/api/stream`,
`/api/health` p50/p99 over 100 calls (no stream open), the time to stop every queued run (one
`POST /api/runs/stop` where the server has it, else one stop per run) and SIGTERM to exit.

    python benchmarks/run_queue_scale.py                          # this checkout
    python benchmarks/run_queue_scale.py --checkout /tmp/before   # another checkout (e.g. before a fix)
"""

from __future__ import annotations

import argparse
import json
import shlex
import shutil
import signal
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx

SLEEPER = [sys.executable, "-c", "import time; time.sleep(3600)"]


def make_folder(template: Path, rows: int) -> None:
    """One ended run's folder, as the trainer leaves it; copied for every ended run."""
    template.mkdir(parents=True)
    (template / "args.json").write_text(
        json.dumps({"argv": [], "seed": 7, "effective": {"num_envs": 4, "max_samples": 64 * rows}})
    )
    (template / "env_config.yaml").write_text("env:\n  motion_file: data/motions/humanoid_demo_squat.pkl\n")
    with open(template / "metrics.jsonl", "w") as f:
        for i in range(rows):
            row = {"iteration": i, "samples": 64 * (i + 1), "wall_time": i / 3600, "test_return": 1.0 * i}
            f.write(json.dumps(row) + "\n")
    (template / "state.json").write_text(json.dumps({"state": "finished", "reason": "reached max_samples"}))
    (template / "model.pt").write_bytes(b"0" * 1024)


def fill_registry(checkout: Path, runs_dir: Path, ended: int, queued: int) -> None:
    sys.path.insert(0, str(checkout))
    from studio.runs.registry import Registry  # the checkout's schema

    Registry(runs_dir / "registry.sqlite")
    template = runs_dir / "template"
    make_folder(template, rows=200)
    arg = str(checkout / "args" / "deepmimic_humanoid_demo_ppo_args.txt")
    now = time.time()
    rows = []
    for i in range(1, ended + queued + 1):
        out_dir = runs_dir / f"{i:04d}-run"
        is_ended = i <= ended
        if is_ended:
            shutil.copytree(template, out_dir)
        status = "finished" if is_ended else "queued"
        rows.append((i, f"run {i}", json.dumps({"arg_file": arg}), status, now, now if is_ended else None,
                     now + 60 if is_ended else None, str(out_dir)))  # fmt: skip
    with sqlite3.connect(runs_dir / "registry.sqlite") as db:
        db.executemany(
            "INSERT INTO runs (id, name, config, status, created_at, started_at, ended_at, out_dir)"
            " VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
            rows,
        )


def timed(fn) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def first_runs_event(url: str) -> float:
    t = time.perf_counter()
    with httpx.stream("GET", url + "api/stream", params={"topics": "runs"}, timeout=120) as r:
        for line in r.iter_lines():
            if line.startswith("event: runs"):
                return time.perf_counter() - t
    return float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkout", type=Path, default=Path(__file__).resolve().parents[1])
    parser.add_argument("--ended", type=int, default=1000)
    parser.add_argument("--queued", type=int, default=4000)
    args = parser.parse_args()
    runs_dir = Path(tempfile.mkdtemp(prefix="run_queue_scale_"))
    fill_registry(args.checkout, runs_dir, args.ended, args.queued)
    argv = [sys.executable, "-m", "studio.cli", "serve", "--port", "0", "--viser-port", "0"]
    argv += ["--runs-dir", str(runs_dir), "--trainer", shlex.join(SLEEPER)]
    proc = subprocess.Popen(argv, cwd=args.checkout, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    url = proc.stdout.readline().split()[-1]
    client = httpx.Client(base_url=url, timeout=300, headers={"X-Studio-Request": "1"})
    try:
        first = timed(lambda: client.get("/api/runs").raise_for_status())
        size = len(client.get("/api/runs").content)
        again = statistics.median(timed(lambda: client.get("/api/runs")) for _ in range(5))
        fresh = []
        for _ in range(5):  # past the run list's 0.5 s cache: each call reads the registry again
            time.sleep(0.6)
            fresh.append(timed(lambda: client.get("/api/runs")))
        print(f"runs: {args.ended} ended + {args.queued} queued; GET /api/runs {size / 1e6:.1f} MB")
        print(f"GET /api/runs: first {first:.2f} s, then median {again:.2f} s back to back,")
        print(f"  median {statistics.median(fresh):.2f} s 0.6 s apart")
        print(f"first 'runs' stream event: {first_runs_event(url):.2f} s")
        health = sorted(timed(lambda: client.get("/api/health")) for _ in range(100))
        print(f"/api/health: p50 {health[50] * 1e3:.0f} ms, p99 {health[98] * 1e3:.0f} ms")
        queued = [r["id"] for r in client.get("/api/runs").json() if r["status"] == "queued"]
        t = time.perf_counter()
        r = client.post("/api/runs/stop", json={"ids": queued})
        if r.status_code in (404, 405, 422):  # a server without the bulk stop: one request per run
            for i in queued:
                client.post(f"/api/runs/{i}/stop")
            how = f"{len(queued)} requests"
        else:
            how = "1 request"
        print(f"stop {len(queued)} queued runs: {time.perf_counter() - t:.2f} s ({how})")
    finally:
        client.close()
        t = time.perf_counter()
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(120)
        except subprocess.TimeoutExpired:
            proc.kill()
        print(f"SIGTERM to exit: {time.perf_counter() - t:.2f} s")
        shutil.rmtree(runs_dir, ignore_errors=True)


if __name__ == "__main__":
    main()
