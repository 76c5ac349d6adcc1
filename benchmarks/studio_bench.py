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

The request loops speak HTTP/1.1 over asyncio streams (`--client raw`, the default with `--duration`): one
keep-alive connection each, the status and the whole body checked. httpx costs the one Python process
that runs all 40 clients about a millisecond of CPU a request, so on two shared cores its p99 measured
mostly the queue in front of the client; `--client httpx` measures with it.

`--rollout-seconds S` then rolls out `--checkpoint` (the demo policy by default) in the scene and reads
its step count from `/api/scene/state` over S seconds: steps/s against its control rate (30/s).
`--page-clicks N` then: headless Chromium at 1280×720 clicks Play/Pause and Step N times each while the
clip plays in the visible 3D view, the page timing each click to its visible change
(benchmarks/page_latency.py), with the page's 3D view at each of `--page-qualities` (default "auto,full").
`--idle-seconds S` last: the rollout closed, the clip paused, no stream and no viser client open, the
server's CPU (user + system, /proc/PID/stat) over S seconds as a share of one core; needs the server
started here or `--server-pid`. All of it inside `--train-cmd`:

    python benchmarks/studio_bench.py --clients 40 --streams 10 --duration 30 --rollout-seconds 20 \
        --idle-seconds 30 --train-cmd "mimickit train --arg_file args/deepmimic_humanoid_demo_ppo_args.txt ..."
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import sys
import time
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

import httpx
import msgspec
import numpy as np
import viser
import websockets
import zstandard

from studio.settings import is_loopback

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.page_latency import click_latency, print_summary, summary  # noqa: E402 - sibling scripts
from benchmarks.studio_server import background, studio_server  # noqa: E402

ENDPOINTS = ["/api/health", "/api/scene/state", "/api/runs", "/api/motions"]
DEMO_ROLLOUT = {
    "checkpoint": "data/models/deepmimic_humanoid_demo_model.pt",
    "env_config": "data/envs/deepmimic_humanoid_env.yaml",
    "agent_config": "data/agents/deepmimic_humanoid_ppo_cpu_agent.yaml",
    "engine_config": "data/engines/mujoco_engine.yaml",
}
CLK_TCK = os.sysconf("SC_CLK_TCK")


async def count_delivered_poses(base: str, seconds: float) -> tuple[int, int, float]:
    """(poses received by a viser client, scene updates the server counted, seconds) over one window.
    The client connects as the page does, through the studio's `/scene` relay (viser's own port takes
    only the relay's requests)."""
    decompress = zstandard.ZstdDecompressor()
    url = base.replace("http", "ws", 1).rstrip("/") + "/scene"
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


class RawClient:
    """HTTP/1.1 GETs on one keep-alive connection over asyncio streams: what a browser's connection
    costs the server, at a small part of httpx's CPU per request on the client's side."""

    def __init__(self, base: str) -> None:
        url = urlparse(base)
        self.host, self.port = url.hostname, url.port
        self.conn: tuple[asyncio.StreamReader, asyncio.StreamWriter] | None = None

    async def get(self, path: str) -> bytes:
        """The body of a 200 answer to `GET path`; ValueError (or an OSError) otherwise."""
        if self.conn is None:
            self.conn = await asyncio.open_connection(self.host, self.port)
        reader, writer = self.conn
        writer.write(f"GET {path} HTTP/1.1\r\nHost: {self.host}:{self.port}\r\nAccept: */*\r\n\r\n".encode())
        try:
            head = (await reader.readuntil(b"\r\n\r\n")).decode("latin-1").split("\r\n")
            headers = dict(h.lower().split(": ", 1) for h in head[1:] if ": " in h)
            if "content-length" not in headers:
                raise ValueError(f"GET {path}: no content-length ({head[0]})")
            body = await reader.readexactly(int(headers["content-length"]))
        except (asyncio.IncompleteReadError, asyncio.LimitOverrunError) as e:
            await self.close()
            raise ValueError(f"GET {path}: the connection broke ({e!r})") from None
        if not head[0].startswith("HTTP/1.1 200 "):
            raise ValueError(f"GET {path}: {head[0]}")
        if headers.get("connection") == "close":
            await self.close()
        return body

    async def close(self) -> None:
        if self.conn is not None:
            self.conn[1].close()
            self.conn = None


async def load_for(
    base: str, clients: int, streams: int, seconds: float, client: str = "raw"
) -> tuple[dict[str, list[float]], int, list[int]]:
    """`clients` GET loops and `streams` open `GET /api/stream` readers for `seconds`: latencies (ms) per
    endpoint, the number of failed requests or streams, and the events each stream received."""
    out: dict[str, list[float]] = {e: [] for e in ENDPOINTS}
    errors, events = [0], [0] * streams
    deadline = time.perf_counter() + seconds

    async def raw_client(k: int) -> None:
        conn, i = RawClient(base), k
        try:
            while time.perf_counter() < deadline:
                path, i = ENDPOINTS[i % len(ENDPOINTS)], i + 1
                t0 = time.perf_counter()
                try:
                    body = await conn.get(path)
                except (OSError, ValueError) as e:
                    errors[0] += 1
                    print(f"  error: {e}", file=sys.stderr)
                    continue
                out[path].append((time.perf_counter() - t0) * 1000)
                if i % 50 == 0:
                    json.loads(body)  # now and then: the body is whole JSON (each time would load the client)
        finally:
            await conn.close()

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

    loops = raw_client if client == "raw" else loop_client
    await asyncio.gather(*(loops(k) for k in range(clients)), *(stream_client(k) for k in range(streams)))
    return out, errors[0], events


def rollout_rate(c: httpx.Client, checkpoint: dict[str, str], seconds: float) -> dict[str, object]:
    """Roll out `checkpoint` in the scene and read its step count each second for `seconds`: steps/s
    overall and the slowest and fastest one-second windows, against the control rate."""
    loaded = c.post("/api/scene/load_rollout", json={**checkpoint, "play": True}).raise_for_status().json()
    time.sleep(2.0)  # past the first steps (torch's first forward passes)
    samples = []
    start = time.perf_counter()
    while True:
        now = time.perf_counter()
        samples.append((now, c.get("/api/scene/state").raise_for_status().json()["rollout"]["step"]))
        if now - start >= seconds:
            break
        time.sleep(1.0)
    c.post("/api/scene/rollout/close", json={}).raise_for_status()
    windows = [(s1 - s0) / (t1 - t0) for (t0, s0), (t1, s1) in zip(samples, samples[1:], strict=False)]
    (t0, s0), (t1, s1) = samples[0], samples[-1]
    return {
        "checkpoint": checkpoint["checkpoint"],
        "num_envs": loaded["rollout"]["envs"]["num_envs"],
        "control_rate": loaded["rollout"]["control_freq"],
        "steps": s1 - s0,
        "seconds": round(t1 - t0, 2),
        "steps_per_s": round((s1 - s0) / (t1 - t0), 1),
        "slowest_1s": round(min(windows), 1),
        "fastest_1s": round(max(windows), 1),
    }


def cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of process `pid` (its threads included) from /proc."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK  # utime, stime (fields 14 and 15)


def idle_cpu(c: httpx.Client, pid: int, seconds: float) -> dict[str, float]:
    """The server's CPU, as a share of one core, over `seconds` with the scene paused and nothing open
    (this client's one connection closed during the window)."""
    c.post("/api/scene/pause", json={}).raise_for_status()
    assert c.get("/api/scene/state").json()["playing"] is False
    c.close()
    time.sleep(3.0)  # the last stream's and viser client's goodbyes
    c0, t0 = cpu_seconds(pid), time.perf_counter()
    time.sleep(seconds)
    cpu, wall = cpu_seconds(pid) - c0, time.perf_counter() - t0
    return {"seconds": round(wall, 1), "cpu_s": round(cpu, 2), "core_percent": round(100 * cpu / wall, 2)}


def percentiles(values: list[float]) -> tuple[float, float]:
    return float(np.percentile(values, 50)), float(np.percentile(values, 99))


def parse_args() -> argparse.Namespace:
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
    ap.add_argument(
        "--client", choices=("raw", "httpx"), default="raw", help="with --duration: what the request loops use"
    )
    ap.add_argument("--rollout-seconds", type=float, help="then: roll out --checkpoint and count its steps/s")
    ap.add_argument("--rollout-envs", type=int, help="the rollout's num_envs (1-16; default: the body's, else 1)")
    ap.add_argument(
        "--checkpoint",
        default=json.dumps(DEMO_ROLLOUT),
        help="the rollout: a JSON body of POST /api/scene/load_rollout (default: the demo policy)",
    )
    ap.add_argument(
        "--page-clicks", type=int, help="then: Chromium clicks Play/Pause/Step while the clip plays (page_latency.py)"
    )
    ap.add_argument("--page-qualities", default="auto,full", help="with --page-clicks: the 3D view settings compared")
    ap.add_argument("--idle-seconds", type=float, help="last: the server's CPU, scene paused, nothing connected")
    ap.add_argument("--server-pid", type=int, help="with --url: the server's pid (for --idle-seconds)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    if args.url and not is_loopback(urlparse(args.url).hostname or ""):
        raise SystemExit("the benchmark only talks to a studio on loopback")
    if args.idle_seconds and args.url and not args.server_pid:
        raise SystemExit("--idle-seconds with --url needs --server-pid (the server's CPU is read from /proc)")
    return args


def measure(args: argparse.Namespace) -> dict[str, Any]:
    """Every measurement, in order, against one server (and inside `--train-cmd`): the raw figures."""
    checkpoint = json.loads(args.checkpoint)
    if args.rollout_envs:  # several envs of the policy at once, drawn on a grid
        checkpoint = {**checkpoint, "num_envs": args.rollout_envs}
    m: dict[str, Any] = {"errors": 0, "events": [], "page": None}
    with (
        studio_server(args) as (base, pid),
        background(args.train_cmd),
        httpx.Client(base_url=base, timeout=60) as c,
    ):
        m["loaded"] = c.post("/api/scene/load_clip", json={"path": args.clip}).raise_for_status().json()
        c.post("/api/scene/configure", json={"speed": args.speed, "loop": True}).raise_for_status()
        c.post("/api/scene/play", json={}).raise_for_status()
        m["poses"], m["updates"], m["seconds"] = asyncio.run(count_delivered_poses(base, args.seconds))
        m["single"] = asyncio.run(api_latency(base, 1, 200))  # service time, without queueing
        if args.duration:
            m["latency"], m["errors"], m["events"] = asyncio.run(
                load_for(base, args.clients, args.streams, args.duration, args.client)
            )
        else:
            m["latency"] = asyncio.run(api_latency(base, args.clients, args.requests))
        m["rollout"] = rollout_rate(c, checkpoint, args.rollout_seconds) if args.rollout_seconds else None
        if args.page_clicks:
            c.post("/api/scene/load_clip", json={"path": args.clip, "play": True}).raise_for_status()
            m["page"] = click_latency(base, args.page_clicks, args.page_qualities.split(","), rounds=1)
        m["idle"] = idle_cpu(c, pid, args.idle_seconds) if args.idle_seconds else None
        if not m["idle"]:
            c.post("/api/scene/pause", json={})
    return m


def summarise(args: argparse.Namespace, m: dict[str, Any]) -> dict[str, Any]:
    """The figures `--json` prints (and the text report reads)."""
    loaded, latency = m["loaded"], m["latency"]
    everything = [v for vs in latency.values() for v in vs]
    result = {
        "clip": args.clip,
        "clip_fps": loaded["fps"],
        "speed": args.speed,
        "target_fps": min(loaded["fps"] * args.speed, 60.0),
        "server_updates_per_s": round(m["updates"] / m["seconds"], 1),
        "client_poses_per_s": round(m["poses"] / m["seconds"], 1),
        "training_in_background": bool(args.train_cmd),
        "api_clients": args.clients,
        "api_requests": len(everything),
        "api_p50_ms": round(percentiles(everything)[0], 1),
        "api_p99_ms": round(percentiles(everything)[1], 1),
        "api_1client_p50_ms": round(percentiles([v for vs in m["single"].values() for v in vs])[0], 2),
        "per_endpoint_ms": {k: [round(x, 1) for x in percentiles(v)] for k, v in latency.items()},
    }
    if args.duration:
        result.update(
            duration_s=args.duration,
            streams=args.streams,
            errors=m["errors"],
            stream_events=m["events"],
            client=args.client,
        )
    result.update(rollout=m["rollout"], idle=m["idle"])
    if m["page"]:
        result["page_click_ms"] = {q: summary(r) for q, r in m["page"].items()}
    return result


def report(args: argparse.Namespace, m: dict[str, Any], result: dict[str, Any]) -> None:
    """The text report: playback, API latency, then the rollout and idle figures when measured."""
    fps, target, seconds = m["loaded"]["fps"], result["target_fps"], m["seconds"]
    print(f"clip {args.clip}: {fps:g} fps x speed {args.speed:g} -> target {target:g} updates/s")
    print(
        f"  playback: server sent {m['updates'] / seconds:.1f} updates/s,"
        f" a viser client received {m['poses'] / seconds:.1f} poses/s"
    )
    print(
        f"  API, {args.clients} concurrent clients, {result['api_requests']} requests: "
        f"p50 {result['api_p50_ms']} ms, p99 {result['api_p99_ms']} ms"
    )
    if args.duration:
        errors, events = m["errors"], m["events"]
        print(f"  for {args.duration:g} s with {args.streams} streams open: {errors} errors, stream events {events}")
        print(f"  (request loops: {args.client} HTTP/1.1 client)")
    print(f"  API, one client: p50 {result['api_1client_p50_ms']} ms")
    for path, (p50, p99) in result["per_endpoint_ms"].items():
        print(f"    {path:<20} p50 {p50:7.1f} ms  p99 {p99:7.1f} ms")
    if rollout := m["rollout"]:
        print(
            f"  rollout of {rollout['checkpoint']} ({rollout['num_envs']} envs): {rollout['steps_per_s']} steps/s"
            f" over {rollout['seconds']} s "
            f"(control rate {rollout['control_rate']:g}/s; 1-s windows {rollout['slowest_1s']}"
            f"-{rollout['fastest_1s']})"
        )
    if m["page"]:
        print_summary("  click to visible change in the page", m["page"])
    if idle := m["idle"]:
        print(
            f"  idle (scene paused, no stream, no viser client): server CPU {idle['core_percent']}% of a core "
            f"({idle['cpu_s']} s in {idle['seconds']} s)"
        )
    if args.train_cmd:
        print(f"  while running: {args.train_cmd}")


def main() -> None:
    args = parse_args()
    m = measure(args)
    result = summarise(args, m)
    if args.json:
        print(json.dumps(result))
        return
    report(args, m, result)


if __name__ == "__main__":
    main()
