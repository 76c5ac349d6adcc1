"""Print how the studio holds up under hostile uploads: `/api/health` latency (p50/p99/max) while
crafted clips are uploaded back to back, against a quiet baseline, and the server's peak memory
(RSS of the server and its child processes, sampled) over the whole run. Loopback only.

    python benchmarks/hostile_bench.py                    # 20 s hostile phase, its own server
    python benchmarks/hostile_bench.py --seconds 60 --rate 20

The hostile phase uploads, in turn and with no pause, the nested-list bomb (4 levels of 90: ~1.4 KB
that expand to 65M numbers), legacy-tensor pickles with out-of-range strides (2**40, negative), a
[64, 34] view over 34 stored floats, a 2**40-element zero-stride view and a valid 2,000,000-frame
clip, while one client asks for `/api/health` at `--rate` per second (the next request goes out at
its slot, or at once when the previous answer came late). Every upload must be refused (4xx); the
counts per status are printed.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path

import httpx
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.hostile import http_payloads as P  # noqa: E402 - the same crafted clips as the test suite

HOSTILE = {
    "nested-list bomb 90^4": P.nested_list_bomb(4, 90),
    "fps stride 2**40": P.stride_fps(2**40),
    "fps stride -1": P.stride_fps(-1),
    "frames [64,34] over 34 floats": P.heap_view_frames(),
    "frames 2**40 x 34, stride 0": P.huge_count_frames(),
    "2,000,000 frames": P.many_frames(),
}


def start_server(runs_dir: str) -> tuple[subprocess.Popen, str]:
    argv = [sys.executable, "-m", "studio.cli", "serve", "--port", "0", "--runs-dir", runs_dir, "--clip", "none"]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, text=True)
    line = proc.stdout.readline()
    if "http://" not in line:
        proc.kill()
        raise SystemExit(f"the studio did not start: {line!r}")
    return proc, line.split()[-1]


def tree_rss_bytes(pid: int) -> int:
    """RSS of `pid` and every descendant (from /proc; processes that end meanwhile are skipped)."""
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        children.setdefault(ppid, []).append(int(entry))
    total, todo = 0, [pid]
    page = os.sysconf("SC_PAGE_SIZE")
    while todo:
        p = todo.pop()
        try:
            total += int(Path(f"/proc/{p}/statm").read_text().split()[1]) * page
        except OSError:
            continue
        todo += children.get(p, [])
    return total


class MemorySampler(threading.Thread):
    """The peak of `tree_rss_bytes(pid)`, sampled every `period` seconds until stopped."""

    def __init__(self, pid: int, period: float = 0.02) -> None:
        super().__init__(daemon=True)
        self.pid, self.period, self.peak, self.samples = pid, period, 0, 0
        self._halt = threading.Event()

    def run(self) -> None:
        while not self._halt.is_set():
            self.peak = max(self.peak, tree_rss_bytes(self.pid))
            self.samples += 1
            time.sleep(self.period)

    def stop(self) -> None:
        self._halt.set()
        self.join()


def health_latencies(base: str, seconds: float, rate: float) -> list[float]:
    """Latencies (ms) of `/api/health` asked `rate` times a second for `seconds`."""
    out: list[float] = []
    with httpx.Client(base_url=base, timeout=120.0) as c:
        c.get("/api/health")  # connect first
        start = time.perf_counter()
        for i in range(int(seconds * rate)):
            slot = start + i / rate
            time.sleep(max(0.0, slot - time.perf_counter()))
            t0 = time.perf_counter()
            c.get("/api/health").raise_for_status()
            out.append((time.perf_counter() - t0) * 1000)
    return out


def upload_loop(base: str, stop: threading.Event, statuses: Counter, per_case: dict[str, list[float]]) -> None:
    with httpx.Client(base_url=base, timeout=300.0, headers={"X-Studio-Request": "1"}) as c:
        while not stop.is_set():
            for name, body in HOSTILE.items():
                if stop.is_set():
                    break
                t0 = time.perf_counter()
                r = c.post("/api/motions/upload", params={"filename": "hostile.pkl"}, content=body)
                per_case.setdefault(name, []).append(time.perf_counter() - t0)
                statuses[(name, r.status_code)] += 1


def summary(ms: list[float]) -> str:
    a = np.asarray(ms)
    p50, p99 = np.percentile(a, 50), np.percentile(a, 99)
    return f"p50 {p50:.1f} ms, p99 {p99:.1f} ms, max {a.max():.1f} ms ({len(a)} requests)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="length of the hostile phase")
    parser.add_argument("--baseline-seconds", type=float, default=5.0)
    parser.add_argument("--rate", type=float, default=20.0, help="health requests per second")
    args = parser.parse_args()

    proc, base = start_server(tempfile.mkdtemp(prefix="hostile_bench_"))
    sampler = MemorySampler(proc.pid)
    sampler.start()
    try:
        idle_rss = tree_rss_bytes(proc.pid)
        quiet = health_latencies(base, args.baseline_seconds, args.rate)
        stop, statuses, per_case = threading.Event(), Counter(), {}
        uploader = threading.Thread(target=upload_loop, args=(base, stop, statuses, per_case))
        uploader.start()
        hostile = health_latencies(base, args.seconds, args.rate)
        stop.set()
        uploader.join()
        alive = proc.poll() is None and httpx.get(base + "api/health", timeout=10).status_code == 200
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
        sampler.stop()

    print(f"server: {base}  (started with --clip none; {os.cpu_count()} CPUs)")
    print(f"/api/health quiet:            {summary(quiet)}")
    print(f"/api/health hostile uploads:  {summary(hostile)}")
    print("uploads (name: status x count, mean seconds to the answer):")
    for name in HOSTILE:
        got = ", ".join(f"{s} x{n}" for (c, s), n in sorted(statuses.items()) if c == name)
        times = per_case.get(name, [])
        print(f"  {name}: {got or '-'}" + (f", {np.mean(times):.2f} s" if times else ""))
    print(f"memory: idle {idle_rss / 2**20:.0f} MB, peak {sampler.peak / 2**20:.0f} MB (server + children, "
          f"{sampler.samples} samples)")  # fmt: skip
    print(f"server still answering after the suite: {alive}")
    accepted = sum(n for (_, s), n in statuses.items() if s < 400)
    if accepted or not alive:
        raise SystemExit(f"FAILED: {accepted} hostile uploads accepted, server alive: {alive}")


if __name__ == "__main__":
    main()
