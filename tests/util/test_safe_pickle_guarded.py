"""`mimickit.util.guarded.run_guarded`: the child-process runner the guarded clip loaders use.

Real child processes throughout: a real sleep overruns the budget, a real allocation hits the
RLIMIT_AS bound, a real segfault kills the child; the parent survives each with one error line.
"""

from __future__ import annotations

import ctypes
import os
import sys
import threading
import time
from pathlib import Path

import pytest

from mimickit.util.errors import MimicKitError
from mimickit.util.guarded import run_guarded

pytestmark = pytest.mark.integration


def echo(data: bytes) -> bytes:
    return data[::-1]


def fail(msg: str) -> bytes:
    raise MimicKitError(msg)


def sleep_long(pid_file: str) -> bytes:
    """Sleeps 20 budgets of 3 s, then leaves a mark: a child the guard failed to stop finishes."""
    Path(pid_file).write_text(str(os.getpid()))
    time.sleep(60)
    Path(pid_file).with_suffix(".finished").touch()
    return b"finished"


def allocate(mb: int) -> bytes:
    block = bytearray(mb * 1024 * 1024)
    return bytes(block[:1])


def segfault() -> bytes:
    ctypes.string_at(0)
    return b""


def not_bytes() -> bytes:
    return "text"  # type: ignore[return-value]


def big_result(n: int) -> bytes:
    return b"x" * n


def loaded_modules() -> bytes:
    return "\n".join(sorted(sys.modules)).encode()


def raises_value_error() -> bytes:
    raise ValueError("line one\nline two")


def test_result_comes_back() -> None:
    assert run_guarded(echo, b"abc", label="x.pkl") == b"cba"


def test_mimickit_error_comes_back_with_its_message() -> None:
    with pytest.raises(MimicKitError, match=r"^x.pkl: bad fps$"):
        run_guarded(fail, "x.pkl: bad fps", label="x.pkl")


def test_other_exceptions_are_one_line_naming_the_label() -> None:
    with pytest.raises(MimicKitError) as e:
        run_guarded(raises_value_error, label="x.pkl")
    assert str(e.value).startswith("x.pkl: ValueError: line one")


def test_time_budget_kills_the_child(tmp_path: Path) -> None:
    """The guard stops the child and says why; checked by what happened (the child is gone before it could
    finish), not by how long the call took (benchmarks/stop_latency.py measures that)."""
    pid_file = tmp_path / "pid"
    with pytest.raises(MimicKitError, match=r"^slow.pkl took longer than 3 s to parse$"):
        run_guarded(sleep_long, str(pid_file), label="slow.pkl", timeout_s=3)
    assert not pid_file.with_suffix(".finished").exists()
    pid = int(pid_file.read_text())
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)


def test_memory_bound() -> None:
    with pytest.raises(MimicKitError, match=r"^big.pkl needs more than 200 MB to parse$"):
        run_guarded(allocate, 400, label="big.pkl", memory_mb=200)
    assert run_guarded(allocate, 50, label="small.pkl", memory_mb=200) == b"\0"


def test_a_segfault_is_one_error() -> None:
    with pytest.raises(MimicKitError, match=r"^crash.pkl: the parser process died \(SIGSEGV\)$"):
        run_guarded(segfault, label="crash.pkl")


def test_result_must_be_bytes_and_bounded() -> None:
    with pytest.raises(MimicKitError, match="not bytes"):
        run_guarded(not_bytes, label="x")
    with pytest.raises(MimicKitError, match="sent more than 1000 bytes"):
        run_guarded(big_result, 5000, label="x", max_result_bytes=1000)


def test_concurrent_calls_from_threads() -> None:
    """The studio calls from worker threads: each call gets its own child and its own answer."""
    results: dict[int, bytes] = {}

    def call(i: int) -> None:
        results[i] = run_guarded(echo, str(i).encode() * 3, label=f"{i}.pkl")

    threads = [threading.Thread(target=call, args=(i,)) for i in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert results == {i: (str(i).encode() * 3)[::-1] for i in range(6)}


def test_the_child_does_not_import_torch() -> None:
    modules = run_guarded(loaded_modules, label="x").decode().split("\n")
    assert "numpy" in modules and "mimickit.util.safe_pickle" in modules
    assert not [m for m in modules if m == "torch" or m.startswith("torch.")]
