"""Wall-time per named phase, for profiles printed by benchmarks (off unless enabled)."""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager


class PhaseTimer:
    def __init__(self) -> None:
        self.enabled = False
        self.totals: dict[str, float] = defaultdict(float)

    @contextmanager
    def phase(self, name: str) -> Iterator[None]:
        if not self.enabled:
            yield
            return
        start = time.perf_counter()
        try:
            yield
        finally:
            self.totals[name] += time.perf_counter() - start

    def reset(self) -> None:
        self.totals.clear()

    def shares(self) -> dict[str, float]:
        total = sum(self.totals.values()) or 1.0
        return {k: v / total for k, v in sorted(self.totals.items(), key=lambda kv: -kv[1])}
