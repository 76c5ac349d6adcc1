"""Hostile values on every field of the run surfaces (launch, sweep values, resume, bulk stop, run ids,
compare), against a real `mimickit-studio serve` whose trainer sleeps (nothing trains). Prints one count
per outcome: `clear 4xx` (one line of under 300 characters), `long 4xx` (more, or several lines),
`accepted` (2xx), `5xx`, `hang` (no answer in 30 s), `dropped` (the connection broke), and `leaked` (an
answer holding a line of /etc/passwd). Accepted runs are stopped at the end with one bulk stop.

    python benchmarks/run_surface_probes.py                          # this checkout
    python benchmarks/run_surface_probes.py --checkout /tmp/before   # another checkout
"""

from __future__ import annotations

import argparse
import json
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
from collections import Counter
from pathlib import Path

import httpx

ARG = "args/deepmimic_humanoid_demo_ppo_args.txt"
SLEEPER = [sys.executable, "-c", "import time; time.sleep(600)"]
# JSON texts, so that Infinity and NaN (which Python's json writes and reads) are sent as such.
VALUES = [
    '"/etc/passwd"', '"data/../../etc/passwd"', '"args/../../etc/passwd"', f'"{"x" * 10_000}"', '""', '"\\u0000"',
    '"cpu --model_file /etc/passwd"', '"--data_dir"', '"# x"', '"a\\nb"', "-1", "0", str(2**63), str(2**64),
    "1e308", "1e400", "Infinity", "NaN", "true", "[]", "{}", '["cpu", "--model_file", "/etc/passwd"]', "null",
]  # fmt: skip
LAUNCH_FIELDS = ["arg_file", "name", "num_envs", "max_samples", "max_hours", "motion_file", "rand_seed",
                 "num_cpus", "num_gpus"]  # fmt: skip
SWEEP_KEYS = ["rand_seed", "motion_file", "num_envs", "max_samples", "max_hours", "engine_config", "env_config",
              "agent_config", "test_episodes", "logger", "devices", "master_port", "save_int_models", "visualize",
              "video", f"{'k' * 10_000}"]  # fmt: skip
IDS = ["0", "-1", str(2**63), str(2**64), "1e3", "x" * 5000, "9" * 5000]


def classify(r: httpx.Response, passwd: list[str]) -> list[str]:
    text = r.text
    out = ["leaked"] if any(line and line in text for line in passwd) else []
    if r.status_code >= 500:
        return [*out, "5xx"]
    if r.status_code < 300:
        return [*out, "accepted"]
    try:
        detail = r.json().get("detail")
    except ValueError:
        detail = None
    ok = isinstance(detail, str) and "\n" not in detail and len(detail) < 300
    return [*out, "clear 4xx" if ok else "long 4xx"]


def probes(run_id: int) -> list[tuple[str, str, str | None]]:
    """(method, path, JSON body text) of every probe; `run_id` an ended run (resume's target)."""
    out: list[tuple[str, str, str | None]] = []
    for field in LAUNCH_FIELDS:
        for v in VALUES:
            base = "" if field == "arg_file" else f'"arg_file": "{ARG}", '
            out.append(("POST", "/api/runs", f'{{{base}"{field}": {v}}}'))
    for key in SWEEP_KEYS:
        for v in VALUES:
            out.append(("POST", "/api/sweeps", f'{{"arg_file": "{ARG}", "values": {{"{key}": [{v}]}}}}'))
    for v in VALUES:
        out.append(("POST", "/api/sweeps", f'{{"arg_file": "{ARG}", "dataset": {v}}}'))
        for field in ("max_samples", "max_hours"):
            out.append(("POST", f"/api/runs/{run_id}/resume", f'{{"{field}": {v}}}'))
        out.append(("POST", "/api/runs/stop", f'{{"ids": [{v}]}}'))
        out.append(("POST", "/api/runs/stop", f'{{"sweep_id": {v}}}'))
    for i in IDS:
        for method, path in (("GET", "/api/runs/{}"), ("POST", "/api/runs/{}/resume"), ("POST", "/api/runs/{}/stop"),
                             ("POST", "/api/runs/{}/again"), ("DELETE", "/api/runs/{}"), ("GET", "/api/runs/{}/log"),
                             ("GET", "/api/sweeps/{}"), ("GET", "/api/compare?runs=1,{}")):  # fmt: skip
            out.append((method, path.format(i), "{}" if method == "POST" else None))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkout", type=Path, default=Path(__file__).resolve().parents[1])
    args = parser.parse_args()
    passwd = [line for line in Path("/etc/passwd").read_text().splitlines() if len(line) > 10][:5]
    runs_dir = Path(tempfile.mkdtemp(prefix="run_surface_probes_"))
    argv = [sys.executable, "-m", "studio.cli", "serve", "--port", "0", "--viser-port", "0"]
    argv += ["--runs-dir", str(runs_dir), "--trainer", shlex.join(SLEEPER)]
    proc = subprocess.Popen(argv, cwd=args.checkout, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    url = proc.stdout.readline().split()[-1]
    headers = {"X-Studio-Request": "1", "Content-Type": "application/json"}
    counts: Counter[str] = Counter()
    try:
        with httpx.Client(base_url=url, timeout=30, headers=headers) as client:
            ended = client.post("/api/runs", content=json.dumps({"arg_file": ARG})).json()["id"]
            client.post(f"/api/runs/{ended}/stop")
            for method, path, body in probes(ended):
                try:
                    counts.update(classify(client.request(method, path, content=body), passwd))
                except httpx.TimeoutException:
                    counts["hang"] += 1
                except httpx.TransportError:
                    counts["dropped"] += 1
            ids = [r["id"] for r in client.get("/api/runs").json() if r["status"] in ("queued", "running")]
            client.post("/api/runs/stop", content=json.dumps({"ids": ids}))
    finally:  # the server (and the sleeping trainer it runs) never outlives the script
        proc.send_signal(signal.SIGTERM)
        proc.wait(60)
        shutil.rmtree(runs_dir, ignore_errors=True)
    print(f"{sum(v for k, v in counts.items() if k != 'leaked')} probes:", dict(counts))


if __name__ == "__main__":
    main()
