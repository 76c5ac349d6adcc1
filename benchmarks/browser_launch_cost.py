"""What the shared Chromium of the browser tests saves (tests/studio/conftest.py): a test module used to
launch its own headless Chromium; it now opens a context of the one the session launched. Prints both
costs (launch + a blank page + close, against new context + a blank page + close), median of `--repeats`.

    python benchmarks/browser_launch_cost.py [--repeats 5]

One run, one machine: the figures move with the load (printed first), compare the two of one run.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import time
from collections.abc import Callable

from playwright.sync_api import sync_playwright

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu"]  # as tests/studio/conftest.py launches it


def median_seconds(repeats: int, fn: Callable[[], None]) -> tuple[float, float]:
    """(median, max) seconds of `fn` over `repeats` calls."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), max(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    if CHROMIUM is None:
        raise SystemExit("no chromium on PATH (apt-get install chromium)")
    print(f"load: {os.getloadavg()[0]:.2f} (1 min), {os.cpu_count()} CPUs")
    with sync_playwright() as p:

        def launch() -> None:
            b = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
            b.new_page().goto("about:blank")
            b.close()

        shared = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)

        def context() -> None:
            c = shared.new_context()
            c.new_page().goto("about:blank")
            c.close()

        own, own_max = median_seconds(args.repeats, launch)
        ctx, ctx_max = median_seconds(args.repeats, context)
        shared.close()
    print(f"own Chromium per module: {own:.2f} s (median of {args.repeats}, max {own_max:.2f} s)")
    print(f"a context of the shared one: {ctx:.2f} s (max {ctx_max:.2f} s); saved per module {own - ctx:.2f} s")


if __name__ == "__main__":
    main()
