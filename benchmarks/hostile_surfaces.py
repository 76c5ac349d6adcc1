"""Count how the studio answers hostile values on every surface that takes a path, an id or a number:
launch, sweep, resume/stop/again/delete, eval and video jobs, rollouts and A/B, export, clip loading,
checkpoint inspection, config reading and compare. Prints one outcome count per class, as the first
hardening round did, each accepted request by name, and `/api/health` latency throughout. Loopback
only; its own server.

    python benchmarks/hostile_surfaces.py                      # this checkout
    python benchmarks/hostile_surfaces.py --checkout /tmp/old  # another checkout (e.g. before a fix)

Classes: `clear error` (a 4xx whose `detail` is one line of at most 300 characters), `long error` (a
4xx that echoes too much or spans lines), `accepted` (2xx), `HTTP 5xx`, `dropped` (the connection
broke), `hang` (no answer in 30 s). Across classes: `leaked` (an answer, a run's reason or log, or a
job's error holds the content of a file outside the folders), `wrote outside` (a file appeared in the
outside folder) and `code executed` (a crafted pickle's payload ran). Accepted runs and jobs are
stopped at the end. The queue cases flood the run queue (5 sweeps of 250 runs), the eval queue (300
jobs) and exports (60 calls), then stop everything.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import numpy as np

ARG = "args/deepmimic_humanoid_demo_ppo_args.txt"
CKPT = "data/models/deepmimic_humanoid_demo_model.pt"
CLIP = "data/motions/humanoid_demo_squat.pkl"
CHAR = "data/assets/humanoid.xml"
MARKER = "HOSTILE_SURFACES_SECRET_7f3a"
HUGE_IDS = {"2^63": 2**63, "2^64": 2**64, "-1": -1, "10^30": 10**30}
TIMEOUT_S = 30.0


@dataclass
class Case:
    surface: str
    name: str
    method: str
    url: str
    body: Any = None
    raw: str | None = None  # a JSON text json.dumps would not write (Infinity, NaN)
    params: dict[str, str] | None = None


class Payload:
    """A pickle whose loading runs `touch <marker file>`: proof that code ran."""

    def __init__(self, flag: Path) -> None:
        self.flag = flag

    def __reduce__(self) -> tuple[Any, ...]:
        return (os.system, (f"touch {self.flag}",))


def outside_files(root: Path) -> dict[str, str]:
    """Files outside every allowed folder: a secret, a malicious checkpoint and clip, an arg file."""
    root.mkdir(parents=True, exist_ok=True)
    flag = root / "code_ran"
    (root / "secret.yaml").write_text(f"{MARKER}: 1\nother_{MARKER}: 2\n")
    for name in ("model.pt", "clip.pkl"):
        (root / name).write_bytes(pickle.dumps(Payload(flag)))
    (root / "args.txt").write_text(f"--env_config {root / 'secret.yaml'}\n")
    return {k: str(root / k) for k in ("secret.yaml", "model.pt", "clip.pkl", "args.txt")}


def hostile_paths(outside: dict[str, str], runs_dir: Path) -> dict[str, str]:
    link = runs_dir / "planted_link.yaml"
    link.symlink_to(outside["secret.yaml"])
    return {
        "/etc/shadow": "/etc/shadow",
        "/etc/passwd": "/etc/passwd",
        "outside secret": outside["secret.yaml"],
        "outside model.pt": outside["model.pt"],
        "outside clip.pkl": outside["clip.pkl"],
        "outside arg file": outside["args.txt"],
        "dot-dot": "data/../../../../etc/passwd",
        "6000 chars": "data/" + "a" * 6000,
        "300-char name": "data/" + "b" * 300 + ".pkl",
        "NUL": "data/x\x00.pkl",
        "runs folder": str(runs_dir),
        "registry.sqlite": str(runs_dir / "registry.sqlite"),
        "/proc/self/environ": "/proc/self/environ",
        "/dev/zero": "/dev/zero",
        "planted symlink": str(link),
        "empty": "",
    }


RUN = {"arg_file": ARG, "num_envs": 2, "max_samples": 64}
VIDEO = {"seconds": 0.5, "width": 64, "height": 64}
# (surface, method, route, a legitimate body, its path fields)
PATH_SURFACES: list[tuple[str, str, str, dict[str, Any], list[str]]] = [
    (
        "launch",
        "POST",
        "/api/runs",
        RUN,
        ["arg_file", "motion_file"],
    ),
    (
        "sweep",
        "POST",
        "/api/sweeps",
        RUN,
        ["arg_file", "motion_file", "dataset"],
    ),
    ("eval", "POST", "/api/evals", {"checkpoint": CKPT, "episodes": 1}, ["checkpoint", "arg_file", "motion_file"]),
    (
        "video",
        "POST",
        "/api/videos",
        {"checkpoint": CKPT, **VIDEO},
        ["checkpoint", "env_config", "agent_config", "engine_config"],
    ),
    (
        "video clip",
        "POST",
        "/api/videos",
        {"clip": CLIP, **VIDEO},
        ["clip", "char"],
    ),
    (
        "rollout",
        "POST",
        "/api/scene/load_rollout",
        {"checkpoint": CKPT, "play": False},
        ["checkpoint", "env_config", "agent_config", "engine_config", "b_checkpoint"],
    ),
    ("export", "POST", "/api/scene/export_replay", {"path": CLIP}, ["path", "char"]),
    ("clip", "POST", "/api/scene/load_clip", {"path": CLIP}, ["path", "char"]),
    ("character", "POST", "/api/scene/show_character", {"path": CHAR}, ["path"]),
]


def path_cases(paths: dict[str, str]) -> list[Case]:
    """Every path field of every surface, one hostile value at a time, the others legitimate."""
    cases = []
    for surface, method, url, base, fields in PATH_SURFACES:
        for key in fields:
            for name, value in paths.items():
                cases.append(Case(f"{surface} {key}", name, method, url, {**base, key: value}))
    for key in (
        "env_config",
        "agent_config",
        "engine_config",
        "motion_file",
        "model_file",
        "data_dir",
        "arg_file",
        "out_dir",
    ):
        for name, value in paths.items():
            body = {"arg_file": ARG, "num_envs": 2, "max_samples": 64, "values": {key: [value]}}
            cases.append(Case(f"sweep values.{key}", name, "POST", "/api/sweeps", body))
    for key, base in (("path", {}), ("path", {"env_config": "data/envs/deepmimic_humanoid_env.yaml"})):
        for name, value in paths.items():
            cases.append(Case("inspect path", name, "GET", "/api/checkpoints/inspect", params={**base, key: value}))
    for name, value in paths.items():
        cases.append(
            Case(
                "inspect env_config",
                name,
                "GET",
                "/api/checkpoints/inspect",
                params={"path": CKPT, "env_config": value},
            )
        )
        cases.append(Case("config file", name, "GET", "/api/configs/file", params={"path": value}))
    return cases


def value_cases(outside: dict[str, str]) -> list[Case]:
    """Argument injection, numbers the trainer would refuse, over-long keys, sweep and id bombs."""
    sweep = {"arg_file": ARG, "num_envs": 2, "max_samples": 64}
    cases = [
        Case(
            "sweep devices",
            "--model_file injected",
            "POST",
            "/api/sweeps",
            {**sweep, "values": {"devices": [f"cpu --model_file {outside['model.pt']}"]}},
        ),
        Case(
            "sweep devices",
            "--data_dir injected",
            "POST",
            "/api/sweeps",
            {**sweep, "values": {"devices": ["cpu --data_dir /"]}},
        ),
        Case("sweep devices", "not a device", "POST", "/api/sweeps", {**sweep, "values": {"devices": ["gpu9"]}}),
        Case("sweep key", "10,000 chars", "POST", "/api/sweeps", {**sweep, "values": {"k" * 10_000: [1]}}),
        Case("sweep key", "--prefixed", "POST", "/api/sweeps", {**sweep, "values": {"--num_envs": [1]}}),
        Case(
            "sweep size",
            "3 keys x 300",
            "POST",
            "/api/sweeps",
            {**sweep, "values": {k: list(range(300)) for k in ("rand_seed", "test_episodes", "master_port")}},
        ),
        Case(
            "sweep size",
            "1 key x 20000",
            "POST",
            "/api/sweeps",
            {**sweep, "values": {"rand_seed": list(range(20_000))}},
        ),
        Case("sweep value", "num_envs 10^12", "POST", "/api/sweeps", {**sweep, "values": {"num_envs": [10**12]}}),
        Case("sweep value", "master_port 70000", "POST", "/api/sweeps", {**sweep, "values": {"master_port": [70_000]}}),
        Case("sweep value", "logger bogus", "POST", "/api/sweeps", {**sweep, "values": {"logger": ["bogus"]}}),
        Case("launch rand_seed", "true", "POST", "/api/runs", {**sweep, "rand_seed": True}),
        Case("launch num_envs", "true", "POST", "/api/runs", {**sweep, "num_envs": True}),
        Case("launch name", "10,000 chars", "POST", "/api/runs", {**sweep, "name": "n" * 10_000}),
        Case("eval episodes", "10^9", "POST", "/api/evals", {"checkpoint": CKPT, "episodes": 10**9}),
        Case(
            "video engine_config",
            "missing",
            "POST",
            "/api/videos",
            {"checkpoint": "data/motions/humanoid_demo_squat.pkl", "seconds": 0.5, "width": 64, "height": 64},
        ),
        Case("video width", "odd", "POST", "/api/videos", {"clip": CLIP, "width": 65, "height": 64}),
    ]
    for raw_name, raw in (("Infinity", "Infinity"), ("NaN", "NaN"), ("1e309", "1e309"), ("-1", "-1")):
        text = json.dumps(sweep)[:-1] + f', "max_hours": {raw}}}'
        cases.append(Case("launch max_hours", raw_name, "POST", "/api/runs", raw=text))
        cases.append(Case("sweep max_hours", raw_name, "POST", "/api/sweeps", raw=text))
    return cases


def id_cases() -> list[Case]:
    """Ids past SQLite's integers (and below zero) on every route and field that takes a run or job id."""
    cases = []
    for name, big in HUGE_IDS.items():
        cases += [
            Case("run get", name, "GET", f"/api/runs/{big}"),
            Case("run resume", name, "POST", f"/api/runs/{big}/resume", {}),
            Case("run stop", name, "POST", f"/api/runs/{big}/stop", {}),
            Case("run again", name, "POST", f"/api/runs/{big}/again", {}),
            Case("run delete", name, "DELETE", f"/api/runs/{big}"),
            Case("run log", name, "GET", f"/api/runs/{big}/log"),
            Case("run metrics", name, "GET", f"/api/runs/{big}/metrics", params={"follow": "false"}),
            Case("sweep get", name, "GET", f"/api/sweeps/{big}"),
            Case("eval get", name, "GET", f"/api/evals/{big}"),
            Case("video get", name, "GET", f"/api/videos/{big}"),
            Case("eval run_id", name, "POST", "/api/evals", {"run_id": big}),
            Case(
                "video run_id", name, "POST", "/api/videos", {"run_id": big, "seconds": 0.5, "width": 64, "height": 64}
            ),
            Case("rollout run_id", name, "POST", "/api/scene/load_rollout", {"run_id": big, "play": False}),
            Case(
                "A/B b_run_id",
                name,
                "POST",
                "/api/scene/load_rollout",
                {"checkpoint": CKPT, "b_run_id": big, "play": False},
            ),
            Case("compare runs", name, "GET", "/api/compare", params={"runs": f"{big},{big}"}),
        ]
    return cases


def classify(r: httpx.Response) -> str:
    if r.status_code >= 500:
        return f"HTTP {r.status_code}"
    if r.status_code < 400:
        return "accepted"
    try:
        detail = r.json().get("detail")
    except (ValueError, AttributeError):
        return "long error"
    ok = isinstance(detail, str) and "\n" not in detail and len(detail) <= 300
    return "clear error" if ok else "long error"


def send(client: httpx.Client, case: Case) -> tuple[str, str]:
    """The outcome class and the answer's text."""
    headers = {"Content-Type": "application/json"}
    content = case.raw if case.raw is not None else (json.dumps(case.body) if case.body is not None else None)
    for attempt in range(2):  # once more on a new connection: a server drops it after an HTTP 500
        try:
            r = client.request(case.method, case.url, content=content, params=case.params, headers=headers)
        except httpx.TimeoutException:
            return "hang", ""
        except httpx.TransportError as e:
            if attempt:
                return "dropped", repr(e)
            continue
        return classify(r), r.text
    raise AssertionError("unreachable")


def call(client: httpx.Client, method: str, url: str, **kwargs: Any) -> httpx.Response:
    """One bookkeeping request, once more on a new connection if the server dropped the last one."""
    try:
        return client.request(method, url, **kwargs)
    except httpx.TransportError:
        return client.request(method, url, **kwargs)


class Health(threading.Thread):
    """`/api/health` asked 10 times a second until stopped; the latencies (ms) and failures."""

    def __init__(self, base: str) -> None:
        super().__init__(daemon=True)
        self.base, self.ms, self.failures = base, [], 0
        self._halt = threading.Event()

    def run(self) -> None:
        with httpx.Client(base_url=self.base, timeout=TIMEOUT_S) as c:
            while not self._halt.is_set():
                t0 = time.perf_counter()
                try:
                    ok = c.get("/api/health").status_code == 200
                except httpx.HTTPError:
                    ok = False
                self.ms.append((time.perf_counter() - t0) * 1000)
                self.failures += not ok
                self._halt.wait(max(0.0, 0.1 - (time.perf_counter() - t0)))

    def stop(self) -> None:
        self._halt.set()
        self.join()


def flood(client: httpx.Client, counts: Counter) -> dict[str, str]:
    """Queue floods: what was accepted, how long the run list then takes, and how everything is stopped."""
    out: dict[str, str] = {}
    sweep = {"arg_file": ARG, "num_envs": 2, "max_samples": 64}
    runs = 0
    sweep_ids = []
    for i in range(5):
        body = {**sweep, "values": {"rand_seed": list(range(i * 250, (i + 1) * 250))}}
        outcome, text = send(client, Case("flood", "sweep of 250", "POST", "/api/sweeps", body))
        counts[outcome] += 1
        if outcome == "accepted":
            runs += len(json.loads(text)["runs"])
            sweep_ids.append(json.loads(text)["id"])
    t0 = time.perf_counter()
    listing = call(client, "GET", "/api/runs")
    out["queued runs accepted"] = f"{runs} of 1250"
    out["GET /api/runs after"] = f"{time.perf_counter() - t0:.2f} s, {len(listing.content) / 1e6:.2f} MB"
    evals = Counter(
        send(client, Case("flood", "eval", "POST", "/api/evals", {"checkpoint": CKPT, "episodes": 1}))[0]
        for _ in range(300)
    )
    out["300 eval jobs"] = ", ".join(f"{k} {v}" for k, v in sorted(evals.items()))
    names, exports = set(), Counter()
    for _ in range(60):
        outcome, text = send(client, Case("flood", "export", "POST", "/api/scene/export_replay", {"path": CLIP}))
        exports[outcome] += 1
        if outcome == "accepted":
            names.add(json.loads(text).get("download"))
    out["60 exports"] = ", ".join(f"{k} {v}" for k, v in sorted(exports.items())) + f"; {len(names)} distinct files"
    t0 = time.perf_counter()
    requests = stop_everything(client, sweep_ids)
    out["stopping every run"] = f"{requests} requests, {time.perf_counter() - t0:.1f} s"
    return out


def stop_everything(client: httpx.Client, sweep_ids: list[int]) -> int:
    """Stop every run and job: the bulk stop where the server has one, else one request a run."""
    requests = 0
    for sid in sweep_ids:
        requests += 1
        if call(client, "POST", "/api/runs/stop", json={"sweep_id": sid}).status_code >= 400:
            break
    for run in call(client, "GET", "/api/runs").json():
        if run["status"] in ("queued", "running"):
            requests += 1
            call(client, "POST", f"/api/runs/{run['id']}/stop", json={})
    for kind in ("evals", "videos"):
        for job in call(client, "GET", f"/api/{kind}").json():
            if job.get("status") in ("queued", "running"):
                requests += 1
                call(client, "POST", f"/api/{kind}/{job['id']}/stop", json={})
    return requests


def wait_for_runs(client: httpx.Client, seconds: float) -> int:
    """Wait until every accepted run has ended (a hostile value shows in its reason only once it ran);
    how many still go at the deadline."""
    deadline = time.monotonic() + seconds
    while True:
        going = sum(r["status"] in ("queued", "running", "stopping") for r in call(client, "GET", "/api/runs").json())
        if not going or time.monotonic() > deadline:
            return going
        time.sleep(2)


def leaks(client: httpx.Client) -> int:
    """Runs and jobs whose reason, log or error holds outside content."""
    found = 0
    for run in call(client, "GET", "/api/runs").json():
        text = json.dumps(run) + "\n".join(call(client, "GET", f"/api/runs/{run['id']}/log").json().get("lines", []))
        found += MARKER in text or "root:" in text
    for kind in ("evals", "videos"):
        found += sum(
            MARKER in json.dumps(j) or "root:" in json.dumps(j) for j in call(client, "GET", f"/api/{kind}").json()
        )
    return found


def start_server(checkout: Path, runs_dir: Path) -> tuple[subprocess.Popen, str]:
    """The studio of `checkout`, its errors in `<runs_dir>/../server.log`."""
    argv = [sys.executable, "-m", "studio.cli", "serve", "--port", "0", "--runs-dir", str(runs_dir), "--clip", "none"]
    argv += ["--max-concurrent-runs", "2"]
    log = open(runs_dir.parent / "server.log", "w")  # noqa: SIM115 - the server's for its whole life
    kw = {"cwd": checkout, "stdout": subprocess.PIPE, "stderr": log, "text": True, "start_new_session": True}
    proc = subprocess.Popen(argv, **kw)
    line = proc.stdout.readline()
    if "http://" not in line:
        proc.kill()
        raise SystemExit(f"the studio did not start: {line!r}")
    return proc, line.split()[-1]


@dataclass
class Tally:
    """Outcomes per class and per surface, leaks in answers, and the accepted requests by name."""

    counts: Counter = field(default_factory=Counter)
    by_surface: Counter = field(default_factory=Counter)
    leaked_answers: int = 0
    accepted: list[str] = field(default_factory=list)

    def add(self, case: Case, outcome: str, text: str) -> None:
        self.counts[outcome] += 1
        self.by_surface[(case.surface, outcome)] += 1
        self.leaked_answers += MARKER in text or "root:" in text
        if outcome == "accepted":
            self.accepted.append(f"{case.surface} = {case.name}")
        if outcome in ("dropped", "hang") or outcome.startswith("HTTP 5"):
            print(f"  {outcome}: {case.surface} = {case.name}", flush=True)

    def report(self, surfaces: int, written: set[str], leaked_runs: int) -> None:
        print(f"{sum(self.counts.values())} hostile requests on {surfaces} surfaces (+ the floods)")
        for outcome, n in self.counts.most_common():
            print(f"  {outcome}: {n}")
        print(f"  leaked (answers / runs and jobs): {self.leaked_answers} / {leaked_runs}")
        print(f"  wrote outside: {len(written - {'code_ran'})}; code executed: {int('code_ran' in written)}")


def after_requests(client: httpx.Client, tally: Tally, flood_too: bool) -> tuple[dict[str, str], int]:
    """Wait for the accepted runs, read their reasons and logs, flood the queues, stop everything."""
    flooded, leaked_runs = {}, -1
    try:
        flooded["runs still going after 15 min"] = str(wait_for_runs(client, 900.0))
        leaked_runs = leaks(client)
        flooded.update(flood(client, tally.counts) if flood_too else {})
        stop_everything(client, [])
        time.sleep(3)  # the failed runs' reasons written
        leaked_runs += leaks(client)
    except (httpx.HTTPError, ValueError) as e:  # the server fell over: said, with what was counted
        flooded["the probe could not finish"] = repr(e)[:200]
    return flooded, leaked_runs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkout", type=Path, default=Path(__file__).resolve().parents[1])
    parser.add_argument("--no-flood", action="store_true", help="skip the queue floods")
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="hostile_surfaces_"))
    runs_dir, outside_dir = work / "runs", work / "outside"
    runs_dir.mkdir()
    outside = outside_files(outside_dir)
    before = set(os.listdir(outside_dir))
    proc, base = start_server(args.checkout.resolve(), runs_dir)
    health = Health(base)
    health.start()
    tally = Tally()
    cases = path_cases(hostile_paths(outside, runs_dir)) + value_cases(outside) + id_cases()
    try:
        with httpx.Client(base_url=base, timeout=TIMEOUT_S) as client:
            for case in cases:
                tally.add(case, *send(client, case))
            flooded, leaked_runs = after_requests(client, tally, not args.no_flood)
    finally:
        health.stop()
        alive = proc.poll() is None
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(60)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
    print(f"checkout {args.checkout}")
    tally.report(len({c.surface for c in cases}), set(os.listdir(outside_dir)) - before, leaked_runs)
    for key, value in flooded.items():
        print(f"  {key}: {value}")
    ms = np.asarray(health.ms)
    print(
        f"/api/health throughout: p50 {np.percentile(ms, 50):.1f} ms, p99 {np.percentile(ms, 99):.1f} ms, "
        f"max {ms.max():.1f} ms, {health.failures} failed of {len(ms)}; server alive at the end: {alive}"
    )
    print("accepted hostile requests: " + "; ".join(tally.accepted))
    bad = sorted({s for (s, o), _ in tally.by_surface.items() if o not in ("clear error", "accepted")})
    if bad:
        print("surfaces with other outcomes: " + ", ".join(bad))


if __name__ == "__main__":
    main()
