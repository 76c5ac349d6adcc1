"""`tune_malloc`: a large tensor freed and allocated again reuses the heap's pages instead of fresh ones,
and glibc's own MALLOC_*_ variables, when a user sets them, stand. Each case in its own process, since
malloc's settings are the process's."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

pytestmark = pytest.mark.integration

# 48 MiB tensors: above the largest mmap threshold glibc's default rises to (32 MiB), so untuned every one
# is a fresh mapping whose pages fault on first write.
SCRIPT = """
import resource, sys, torch
from mimickit.util.malloc_tuning import tune_malloc
applied = tune_malloc() if sys.argv[1] == "tuned" else None
def cycle():
    x = torch.empty(12 << 20)
    x.fill_(1.0)
cycle()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):
    cycle()
print(applied is not None, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def page_faults(mode: str, **env: str) -> tuple[bool, int]:
    """(whether tune_malloc changed anything, minor page faults of 20 allocate-write-free cycles)."""
    full_env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")} | env
    out = subprocess.run([sys.executable, "-c", SCRIPT, mode], capture_output=True, text=True, check=True, env=full_env)
    applied, faults = out.stdout.split()
    return applied == "True", int(faults)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc")
def test_tuned_malloc_reuses_freed_tensors_pages() -> None:
    applied, tuned = page_faults("tuned")
    _, plain = page_faults("plain")
    assert applied
    assert plain > 20 * (48 << 20) // 4096 * 0.9  # untuned: every cycle faults in its 48 MiB afresh
    assert tuned < plain / 2, (tuned, plain)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc")
def test_a_users_glibc_variables_stand() -> None:
    applied, faults = page_faults("tuned", MALLOC_TOP_PAD_="131072")
    _, plain = page_faults("plain", MALLOC_TOP_PAD_="131072")
    assert not applied
    assert faults == pytest.approx(plain, rel=0.1)
