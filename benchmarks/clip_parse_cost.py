"""Time parsing every real clip in-process (`load_motion`) and, where it exists, through the
guarded child process (`load_motion_guarded`), plus the child's start-up cost.

MIMICKIT_TEST_DATA=../shared/data python benchmarks/clip_parse_cost.py [--repeats 5]

Prints the best-of-N total over all clips (best of N damps the noise of a shared machine), wall
and CPU time, the largest clip alone, and for the child runner: the cost of one guarded call on a tiny clip (start-up
plus transfer) and the guarded total over all clips.
"""

from __future__ import annotations

import argparse
import os
import pickle
import tempfile
import time
import warnings
from pathlib import Path

from mimickit.anim import motion as motion_mod


def best_of(repeats: int, fn, clock=time.perf_counter) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = clock()
        fn()
        best = min(best, clock() - t0)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    paths = sorted((Path(os.environ["MIMICKIT_TEST_DATA"]) / "motions").rglob("*.pkl"))
    total_mb = sum(p.stat().st_size for p in paths) / 2**20
    largest = max(paths, key=lambda p: p.stat().st_size)
    warnings.simplefilter("ignore")

    def load_all() -> None:
        for p in paths:
            motion_mod.load_motion(p)

    # CPU time of this process as well as wall time: on a shared machine the wall clock mostly
    # measures the other processes; the parse is single-threaded, so its CPU time is its cost.
    for name, clock in (("wall", time.perf_counter), ("cpu", time.process_time)):
        t_all = best_of(args.repeats, load_all, clock)
        t_big = best_of(args.repeats, lambda: motion_mod.load_motion(largest), clock)
        print(
            f"in-process ({name}): {len(paths)} clips, {total_mb:.1f} MB: {t_all * 1e3:.0f} ms"
            f" ({t_all / total_mb * 1e3:.1f} ms/MB); largest {largest.name}"
            f" ({largest.stat().st_size / 2**20:.2f} MB): {t_big * 1e3:.1f} ms"
        )

    guarded = getattr(motion_mod, "load_motion_guarded", None)
    if guarded is None:
        print("guarded: load_motion_guarded not present in this version")
        return
    with tempfile.TemporaryDirectory() as d:
        tiny = Path(d) / "tiny.pkl"
        tiny.write_bytes(pickle.dumps({"loop_mode": 0, "fps": 30, "frames": [[0.0] * 34] * 2}))
        t0 = time.perf_counter()
        guarded(tiny)
        first = time.perf_counter() - t0
        t_tiny = best_of(max(args.repeats, 10), lambda: guarded(tiny))
    print(f"guarded: first call (starts the fork server) {first * 1e3:.0f} ms; a later tiny clip {t_tiny * 1e3:.1f} ms")
    t_gall = best_of(min(args.repeats, 2), lambda: [guarded(p) for p in paths])
    per_clip = t_gall / len(paths) * 1e3
    print(f"guarded: {len(paths)} clips one child each: {t_gall * 1e3:.0f} ms ({per_clip:.1f} ms/clip)")


if __name__ == "__main__":
    main()
