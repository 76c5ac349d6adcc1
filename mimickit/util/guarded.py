"""Run one parse of untrusted data in a child process with a time budget and a memory bound.

A crafted file can spend seconds inside C code that holds the GIL, ask for gigabytes, or (before
the loaders were hardened) crash the interpreter; none of that may reach a long-lived process such
as the studio server. `run_guarded(fn, *args, ...)` runs `fn(*args) -> bytes` in a child started
from a fork server ("forkserver": the server is a fresh single-threaded interpreter, so forking it
is safe where forking the threaded studio is not; it preloads numpy and the clip loader, so a child
starts in milliseconds). The child caps its address space with RLIMIT_AS at its start-up size plus
`memory_mb`; the parent kills it once `timeout_s` has passed. The answer comes back as raw bytes
(no pickle from the child), and every failure is one MimicKitError naming `label`.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import threading
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Any

from mimickit.util.errors import MimicKitError

_PRELOAD = ["mimickit.anim.motion"]  # numpy + safe_pickle: what a clip parse needs, no torch
_ctx_lock = threading.Lock()
_ctx: Any = None
_OK, _ERR = b"R", b"E"


def run_guarded(
    fn: Callable[..., bytes],
    *args: Any,
    label: str,
    timeout_s: float = 5.0,
    memory_mb: float = 2048.0,
    max_result_bytes: int = 1 << 30,
) -> bytes:
    """`fn(*args)` run in a child process; its bytes, or one MimicKitError.

    `fn` must be a module-level function (the child imports it by name) returning bytes; a
    MimicKitError it raises comes back with its message. The errors: "<label> took longer than
    <timeout_s> s to parse", "<label> needs more than <memory_mb> MB to parse", "<label>: the parser
    process died (<signal>)". Blocks the calling thread for at most about `timeout_s`.
    """
    ctx = _context()
    receiver, sender = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child_main, args=(sender, fn, args, label, memory_mb), daemon=True)
    try:
        try:
            proc.start()
        except OSError as e:
            raise MimicKitError(f"{label}: cannot start the parser process ({e})") from None
        finally:
            sender.close()
        return _receive(receiver, proc, label, timeout_s, max_result_bytes)
    finally:
        if proc.is_alive():
            proc.kill()
        if proc.pid is not None:
            proc.join(5)
        receiver.close()


def _receive(receiver: Connection, proc: Any, label: str, timeout_s: float, max_bytes: int) -> bytes:
    if not receiver.poll(timeout_s):
        raise MimicKitError(f"{label} took longer than {timeout_s:g} s to parse")
    try:
        tag = receiver.recv_bytes(16)
        body = receiver.recv_bytes(max_bytes)
    except EOFError:
        proc.join(5)
        raise MimicKitError(f"{label}: the parser process died ({_exit_reason(proc.exitcode)})") from None
    except OSError:
        raise MimicKitError(f"{label}: the parser process sent more than {max_bytes} bytes") from None
    if tag == _OK:
        return body
    if tag == _ERR:
        raise MimicKitError(body.decode("utf-8", "replace")[:2000])
    raise MimicKitError(f"{label}: the parser process sent a malformed result")


def _exit_reason(code: int | None) -> str:
    if code is None:
        return "still running"
    if code < 0:
        try:
            return signal.Signals(-code).name
        except ValueError:
            return f"signal {-code}"
    return f"exit code {code}"


def _context() -> Any:
    global _ctx
    with _ctx_lock:
        if _ctx is None:
            ctx = multiprocessing.get_context("forkserver")
            # '__main__' (the default) first: each child would otherwise import the caller's main
            # module itself, as spawn does; the server imports it once.
            ctx.set_forkserver_preload(["__main__", *_PRELOAD])
            _ctx = ctx
        return _ctx


def _child_main(conn: Connection, fn: Callable[..., bytes], args: tuple, label: str, memory_mb: float) -> None:
    # Made before the bound: while a MemoryError is handled, its traceback still holds the memory.
    out_of_memory = f"{label} needs more than {memory_mb:g} MB to parse".encode()
    try:
        _limit_memory(memory_mb)
        result = fn(*args)
        if not isinstance(result, bytes):
            raise TypeError(f"{fn.__name__} returned {type(result).__name__}, not bytes")
        tag, body = _OK, result
    except MemoryError:
        tag, body = _ERR, out_of_memory
    except MimicKitError as e:
        tag, body = _ERR, str(e).encode("utf-8", "replace")
    except BaseException as e:  # noqa: BLE001 - untrusted input: any failure is one line for the caller
        tag, body = _ERR, f"{label}: {type(e).__name__}: {str(e)[:300]}".encode("utf-8", "replace")
    try:
        conn.send_bytes(tag)
        conn.send_bytes(body)
    finally:
        conn.close()


def _limit_memory(memory_mb: float) -> None:
    """Cap this process's address space at its current size plus `memory_mb` (Linux: RLIMIT_AS)."""
    import resource

    current = _address_space_bytes()
    if current is None:
        return
    cap = current + int(memory_mb * 1024 * 1024)
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    if hard != resource.RLIM_INFINITY:
        cap = min(cap, hard)
    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))


def _address_space_bytes() -> int | None:
    try:
        with open(f"/proc/{os.getpid()}/status") as f:
            for line in f:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        return None
    return None
