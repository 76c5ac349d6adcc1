"""Print what the studio server delivers: clip playback frames per second (as a viser client receives
them) and REST API latency (p50/p99) under 50 concurrent clients. Loopback only.

    python benchmarks/studio_bench.py                       # starts its own server on free ports
    python benchmarks/studio_bench.py --url http://127.0.0.1:8000/
    python benchmarks/studio_bench.py --train-cmd "mimickit train --arg_file args/... --out_dir /tmp/b"

Playback: the clip is played at `--speed`; a websocket client speaking viser's protocol counts the
messages that carry a new character pose (what a browser would draw) over `--seconds`, beside the
server's own count of scene updates. Latency: `--requests` GETs spread over `--clients` concurrent
httpx clients, round robin over health, scene state, runs and motions, while the clip keeps playing.
`--train-cmd` runs a command (e.g. a training run) in the background during both measurements.
`--duration S --streams N`: instead, `--clients` request loops and N open `/api/stream` readers for S seconds
(errors counted):

    python benchmarks/studio_bench.py --clients 40 --streams 10 --duration 30 --train-cmd "mimickit train ..."
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import shlex
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from urllib.parse import urlparse

import httpx
import msgspec
import numpy as np
import viser
import websockets
import zstandard

from studio.settings import is_loopback

ENDPOINTS = ["/api/health", "/api/scene/state", "/api/runs", "/api/motions"]


@contextmanager
def studio_server(args: argparse.Namespace) -> Iterator[str]:
    """The URL of a server: the one given, or one started here for the run of the benchmark."""
    if args.url:
        yield args.url.rstrip("/") + "/"
        return
    runs_dir = tempfile.mkdtemp(prefix="studio_bench_")
    argv = [sys.executable, "-m", "studio.cli", "serve", "--port", "0", "--runs-dir", runs_dir]
    if args.data_dir:
        argv += ["--data-dir", args.data_dir]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        if "http://" not in line:
            raise SystemExit(f"the studio did not start: {line!r}")
        yield line.split()[-1]
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(20)


@contextmanager
def background(cmd: str | None) -> Iterator[None]:
    """Run `cmd` (its own process group) for the duration of the block."""
    if not cmd:
        yield
        return
    proc = subprocess.Popen(shlex.split(cmd), start_new_session=True, stdout=subprocess.DEVNULL)
    try:
        time.sleep(2.0)  # let it get past its start-up
        yield
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(60)


async def count_delivered_poses(base: str, viser_port: int, seconds: float) -> tuple[int, int, float]:
    """(poses received by a viser client, scene updates the server counted, seconds) over one window."""
    decompress = zstandard.ZstdDecompressor()
    url = f"ws://127.0.0.1:{viser_port}"
    async with websockets.connect(url, subprotocols=[f"viser-v{viser.__version__}"], max_size=None) as ws:
        # The first messages replay the whole scene; start counting after a quiet moment of that.
        await asyncio.sleep(1.0)
        while True:
            try:
                await asyncio.wait_for(ws.recv(), timeout=0.001)
            except asyncio.TimeoutError:
                break
        async with httpx.AsyncClient(base_url=base) as api:
            first = (await api.get("/api/scene/state")).json()["updates"]
        poses, start = 0, time.perf_counter()
        while (elapsed := time.perf_counter() - start) < seconds:
            try:
                data = await asyncio.wait_for(ws.recv(), timeout=seconds - elapsed)
            except asyncio.TimeoutError:
                break
            raw, packed = int.from_bytes(data[:8], "little"), int.from_bytes(data[8:16], "little")
            window = msgspec.msgpack.decode(decompress.decompress(data[16 : 16 + packed], max_output_size=raw))
            # One window may hold several updates when the client lags; it still shows one pose.
            if any(m.get("name", "").startswith("/bodies/") for m in window["messages"]):
                poses += 1
        elapsed = time.perf_counter() - start
        async with httpx.AsyncClient(base_url=base) as api:
            last = (await api.get("/api/scene/state")).json()["updates"]
        return poses, last - first, elapsed


async def api_latency(base: str, clients: int, requests: int) -> dict[str, list[float]]:
    """Latencies (ms) per endpoint for `requests` GETs split over `clients` concurrent clients.

    Each client is its own httpx.AsyncClient with one keep-alive connection, as 50 browsers would be;
    one shared pool of 50 connections measures httpx's pool lock more than the server (p99 > 1 s even
    against an empty FastAPI app on this machine).
    """
    out: dict[str, list[float]] = {e: [] for e in ENDPOINTS}
    counter = iter(range(requests))
    barrier = asyncio.Barrier(clients)

    async def one_client() -> None:
        async with httpx.AsyncClient(base_url=base, timeout=60) as client:
            await client.get(ENDPOINTS[0])  # connect first: the steady state is what is measured
            await barrier.wait()
            for i in counter:  # the shared iterator bounds the total number of requests
                path = ENDPOINTS[i % len(ENDPOINTS)]
                t0 = time.perf_counter()
                r = await client.get(path)
                out[path].append((time.perf_counter() - t0) * 1000)
                r.raise_for_status()

    await asyncio.gather(*(one_client() for _ in range(clients)))
    return out


async def load_for(
    base: str, clients: int, streams: int, seconds: float
) -> tuple[dict[str, list[float]], int, list[int]]:
    """`clients` GET loops and `streams` open `GET /api/stream` readers for `seconds`: latencies (ms) per
    endpoint, the number of failed requests or streams, and the events each stream received."""
    out: dict[str, list[float]] = {e: [] for e in ENDPOINTS}
    errors, events = [0], [0] * streams
    deadline = time.perf_counter() + seconds

    async def loop_client(k: int) -> None:
        async with httpx.AsyncClient(base_url=base, timeout=60) as client:
            i = k
            while time.perf_counter() < deadline:
                path, i = ENDPOINTS[i % len(ENDPOINTS)], i + 1
                t0 = time.perf_counter()
                try:
                    (await client.get(path)).raise_for_status()
                except httpx.HTTPError:
                    errors[0] += 1
                    continue
                out[path].append((time.perf_counter() - t0) * 1000)

    async def stream_client(k: int) -> None:
        async with httpx.AsyncClient(base_url=base, timeout=60) as client:
            try:
                async with client.stream("GET", "/api/stream") as r:
                    r.raise_for_status()
                    async for line in r.aiter_lines():
                        events[k] += line.startswith("event:")
                        if time.perf_counter() > deadline:
                            break
            except httpx.HTTPError:
                errors[0] += 1

    await asyncio.gather(*(loop_client(k) for k in range(clients)), *(stream_client(k) for k in range(streams)))
    return out, errors[0], events


def percentiles(values: list[float]) -> tuple[float, float]:
    return float(np.percentile(values, 50)), float(np.percentile(values, 99))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--url", help="a running studio (loopback only); default: start one")
    ap.add_argument("--data-dir", help="--data-dir for the server started here")
    ap.add_argument("--clip", default="data/motions/humanoid_demo_squat.pkl")
    ap.add_argument("--speed", type=float, default=1.0)
    ap.add_argument("--seconds", type=float, default=5.0, help="playback measurement time")
    ap.add_argument("--clients", type=int, default=50)
    ap.add_argument("--requests", type=int, default=2000, help="total API requests")
    ap.add_argument("--train-cmd", help="a command to run in the background while measuring")
    ap.add_argument("--streams", type=int, default=0, help="with --duration: open /api/stream readers")
    ap.add_argument(
        "--duration", type=float, help="instead of --requests: --clients GET loops (and --streams) for this long"
    )
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    if args.url and not is_loopback(urlparse(args.url).hostname or ""):
        raise SystemExit("the benchmark only talks to a studio on loopback")

    with studio_server(args) as base, background(args.train_cmd), httpx.Client(base_url=base, timeout=60) as c:
        viser_port = c.get("/api/health").json()["viser_port"]
        loaded = c.post("/api/scene/load_clip", json={"path": args.clip}).raise_for_status().json()
        c.post("/api/scene/configure", json={"speed": args.speed, "loop": True}).raise_for_status()
        c.post("/api/scene/play", json={}).raise_for_status()
        poses, updates, seconds = asyncio.run(count_delivered_poses(base, viser_port, args.seconds))
        single = asyncio.run(api_latency(base, 1, 200))  # service time, without queueing
        errors, events = 0, []
        if args.duration:
            latency, errors, events = asyncio.run(load_for(base, args.clients, args.streams, args.duration))
        else:
            latency = asyncio.run(api_latency(base, args.clients, args.requests))
        c.post("/api/scene/pause", json={})

    server_fps = updates / seconds
    target = min(loaded["fps"] * args.speed, 60.0)
    everything = [v for vs in latency.values() for v in vs]
    result = {
        "clip": args.clip,
        "clip_fps": loaded["fps"],
        "speed": args.speed,
        "target_fps": target,
        "server_updates_per_s": round(server_fps, 1),
        "client_poses_per_s": round(poses / seconds, 1),
        "training_in_background": bool(args.train_cmd),
        "api_clients": args.clients,
        "api_requests": len(everything),
        "api_p50_ms": round(percentiles(everything)[0], 1),
        "api_p99_ms": round(percentiles(everything)[1], 1),
        "api_1client_p50_ms": round(percentiles([v for vs in single.values() for v in vs])[0], 2),
        "per_endpoint_ms": {k: [round(x, 1) for x in percentiles(v)] for k, v in latency.items()},
    }
    if args.duration:
        result.update(duration_s=args.duration, streams=args.streams, errors=errors, stream_events=events)
    if args.json:
        print(json.dumps(result))
        return
    print(f"clip {args.clip}: {loaded['fps']:g} fps x speed {args.speed:g} -> target {target:g} updates/s")
    print(f"  playback: server sent {server_fps:.1f} updates/s, a viser client received {poses / seconds:.1f} poses/s")
    print(
        f"  API, {args.clients} concurrent clients, {len(everything)} requests: "
        f"p50 {result['api_p50_ms']} ms, p99 {result['api_p99_ms']} ms"
    )
    if args.duration:
        print(f"  for {args.duration:g} s with {args.streams} streams open: {errors} errors, stream events {events}")
    print(f"  API, one client: p50 {result['api_1client_p50_ms']} ms")
    for path, (p50, p99) in result["per_endpoint_ms"].items():
        print(f"    {path:<20} p50 {p50:7.1f} ms  p99 {p99:7.1f} ms")
    if args.train_cmd:
        print(f"  while running: {args.train_cmd}")


if __name__ == "__main__":
    main()
