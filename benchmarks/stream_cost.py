"""Print what `GET /api/stream` costs the server: its CPU (user + system time of the server process,
from /proc, as a share of one core) over `--seconds` with 0, 1 and `--streams` streams open, the scene
paused and then playing, and the events each stream received per second. Starts its own server
(loopback, free port, the demo squat); Linux only (reads /proc/PID/stat).

    python benchmarks/stream_cost.py
    python benchmarks/stream_cost.py --seconds 20 --streams 10
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

import httpx

CLK_TCK = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK  # utime, stime (fields 14 and 15)


def open_streams(url: str, n: int, stop: threading.Event, counts: list[int]) -> list[threading.Thread]:
    def read(i: int) -> None:
        with httpx.Client(timeout=30) as c, c.stream("GET", url + "api/stream") as r:
            for line in r.iter_lines():
                if line.startswith("event: "):
                    counts[i] += 1
                if stop.is_set():
                    return

    threads = [threading.Thread(target=read, args=(i,), daemon=True) for i in range(n)]
    for t in threads:
        t.start()
    return threads


def measure(url: str, pid: int, streams: int, seconds: float) -> tuple[float, float]:
    """(share of one core, events per stream per second) over `seconds` with `streams` open."""
    stop, counts = threading.Event(), [0] * streams
    threads = open_streams(url, streams, stop, counts)
    time.sleep(2.0)  # connected, backlog sent
    start_counts, c0, t0 = sum(counts), cpu_seconds(pid), time.monotonic()
    time.sleep(seconds)
    cpu, wall = cpu_seconds(pid) - c0, time.monotonic() - t0
    events = (sum(counts) - start_counts) / wall / max(streams, 1)
    stop.set()  # each reader leaves at its next line (a heartbeat within 5 s at most)
    for t in threads:
        t.join(10)
    time.sleep(1.0)
    return cpu / wall, events


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--streams", type=int, default=10)
    args = parser.parse_args()
    runs_dir = tempfile.mkdtemp(prefix="stream_cost_")
    argv = [sys.executable, "-m", "studio.cli", "serve", "--port", "0", "--runs-dir", runs_dir]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, text=True)
    try:
        url = proc.stdout.readline().split()[-1]
        client = httpx.Client(base_url=url, headers={"X-Studio-Request": "1"}, timeout=30)
        time.sleep(5.0)  # the library warm-up reads every clip once: let it finish
        print(f"server pid {proc.pid}, {args.seconds:g} s per row; CPU = share of one core")
        print(f"{'scene':8} {'streams':>7} {'server CPU':>11} {'events/s per stream':>20}")
        for scene in ("paused", "playing"):
            client.post("/api/scene/pause" if scene == "paused" else "/api/scene/play")
            for n in (0, 1, args.streams):
                cpu, events = measure(url, proc.pid, n, args.seconds)
                print(f"{scene:8} {n:7d} {100 * cpu:10.1f}% {events if n else float('nan'):20.1f}")
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(20)


if __name__ == "__main__":
    main()
