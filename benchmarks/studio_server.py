"""The studio server and the background command the studio benchmarks measure against
(`studio_bench.py`, `page_latency.py`): a running studio given by URL, or one started here on free ports
for the measurement; a command (e.g. a training run) in its own process group for the duration."""

from __future__ import annotations

import argparse
import os
import shlex
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def studio_server(args: argparse.Namespace) -> Iterator[tuple[str, int | None]]:
    """The URL and pid (None if unknown) of a server: the one given, or one started here for the run."""
    if args.url:
        yield args.url.rstrip("/") + "/", args.server_pid
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
        yield line.split()[-1], proc.pid
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
