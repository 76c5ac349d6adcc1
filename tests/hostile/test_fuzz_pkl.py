"""Fuzz the clip loader (issue 17): >= 500 mutated and crafted pickles, each a valid clip or one error.

Inputs (seeded, so a failure reproduces): byte flips, overwrites with boundary values, truncations,
insertions, duplicated slices and splices of real clips; every crafted case of pkl_cases.py; and
random opcode streams. They run through `motion_from_bytes` in guarded child processes, 50 to a
child with a per-input alarm (`pkl_cases.classify_batch`); a batch whose child dies or overruns is
run again one input per child, so a crash is pinned to its input. The test fails on any crash,
hang (> 5 s), memory error under the child's bound, frames not taken from the file, or anything
but a clip or one MimicKitError line.
"""

from __future__ import annotations

import collections
import ctypes
import json
import pickletools
import random
import time
from collections.abc import Callable

import pytest

from mimickit.util.errors import MimicKitError
from mimickit.util.guarded import run_guarded
from tests import conftest
from tests.hostile.pkl_cases import all_cases, classify_batch

pytestmark = pytest.mark.integration

SEED = 17
BATCH = 50
PER_INPUT_S = 5.0
MEMORY_MB = 1536
SEED_CLIPS = ["humanoid/humanoid_double_kong.pkl", "go2/go2_trot.pkl", "g1/g1_cartwheel.pkl"]
BOUNDARY = [b"\xff\xff\xff\xff", b"\xff\xff\xff\x7f", b"\x00\x00\x00\x80", b"\x00\x00\x00\x00", b"\x01\x00\x00\x00"]
ALLOWED_GLOBALS = [
    b"ctorch._utils\n_rebuild_tensor_v2\n",
    b"ctorch.storage\n_load_from_bytes\n",
    b"cnumpy.core.multiarray\n_reconstruct\n",
    b"cnumpy\nndarray\n",
    b"cnumpy\ndtype\n",
    b"cnumpy.core.multiarray\nscalar\n",
    b"ccollections\nOrderedDict\n",
    b"c_codecs\nencode\n",
]


def _seeds() -> list[bytes]:
    seeds = [conftest.DEMO_CLIP.read_bytes()]
    data = conftest.test_data_dir()
    if data is not None:
        seeds += [(data / "motions" / rel).read_bytes() for rel in SEED_CLIPS]
    seeds += [c.data for c in all_cases() if c.outcome == "ok" and c.id.startswith(("ok-tensor", "ok-numpy"))]
    return seeds


def _mutate(rng: random.Random, seeds: list[bytes]) -> bytes:
    b = bytearray(rng.choice(seeds))
    if not b:
        return rng.randbytes(rng.randint(1, 16))
    kind = rng.randrange(6)
    if kind == 0:  # flip a few bytes
        for _ in range(rng.randint(1, 8)):
            b[rng.randrange(len(b))] = rng.randrange(256)
    elif kind == 1:  # a boundary value where a length or index may be
        i = rng.randrange(len(b))
        b[i : i + 4] = rng.choice(BOUNDARY)
    elif kind == 2:  # truncate
        del b[rng.randrange(len(b)) :]
    elif kind == 3:  # insert random bytes or an allowed global
        i = rng.randrange(len(b))
        b[i:i] = rng.choice(ALLOWED_GLOBALS) if rng.random() < 0.3 else rng.randbytes(rng.randint(1, 16))
    elif kind == 4:  # duplicate a slice
        i = rng.randrange(len(b))
        j = min(len(b), i + rng.randint(1, 2000))
        b[j:j] = b[i:j]
    else:  # splice two inputs
        other = rng.choice(seeds)
        b = b[: rng.randrange(len(b))] + other[rng.randrange(len(other)) :]
    return bytes(b)


_OPS = [op for op in pickletools.opcodes if op.proto <= 5]
_COUNTED = {  # argument kinds whose first bytes give the length of the rest: their width
    pickletools.TAKEN_FROM_ARGUMENT1: 1,
    pickletools.TAKEN_FROM_ARGUMENT4: 4,
    pickletools.TAKEN_FROM_ARGUMENT4U: 4,
    pickletools.TAKEN_FROM_ARGUMENT8U: 8,
}


def _random_opcodes(rng: random.Random) -> bytes:
    """A random opcode stream with arguments of plausible sizes, ending in STOP."""
    out = bytearray(b"\x80" + bytes([rng.randint(2, 5)]))
    for _ in range(rng.randint(1, 60)):
        if rng.random() < 0.1:
            out += rng.choice(ALLOWED_GLOBALS)
            continue
        op = rng.choice(_OPS)
        out += op.code.encode("latin1")
        n = op.arg.n if op.arg is not None else 0
        if n > 0:
            out += rng.randbytes(n) if rng.random() < 0.5 else rng.randrange(1 << min(8 * n, 16)).to_bytes(n, "little")
        elif n == pickletools.UP_TO_NEWLINE:
            out += rng.choice([b"0", b"12", b"1.5", b"'ab'", b"os", b"x" * rng.randint(0, 20)]) + b"\n"
        elif n in _COUNTED:
            width = _COUNTED[n]
            k = rng.randint(0, 12) if rng.random() < 0.9 else rng.randrange(1 << min(8 * width - 1, 31))
            out += k.to_bytes(width, "little") + rng.randbytes(min(k, 12))
    return bytes(out + b".")


def _inputs() -> list[bytes]:
    rng = random.Random(SEED)
    seeds = _seeds()
    crafted = [c.data for c in all_cases()]
    mutated = [_mutate(rng, seeds) for _ in range(600)]
    crafted_mutated = [_mutate(rng, crafted) for _ in range(150)]
    opcodes = [_random_opcodes(rng) for _ in range(300)]
    return crafted + mutated + crafted_mutated + opcodes


def _run_batch(blobs: list[bytes], fn: Callable[..., bytes] = classify_batch) -> list[dict]:
    """Outcomes of `blobs`: one child for the batch, or one child each when the batch's child fails."""
    try:
        timeout = 15 + 2 * len(blobs)
        return json.loads(
            run_guarded(fn, blobs, PER_INPUT_S, label="fuzz batch", timeout_s=timeout, memory_mb=MEMORY_MB)
        )
    except MimicKitError:
        if len(blobs) == 1:
            raise
    out = []
    for blob in blobs:
        try:
            out += _run_batch([blob], fn)
        except MimicKitError as e:  # the child died, overran or ran out of memory on this input
            out.append({"kind": "child-failed", "detail": str(e)[:300], "s": None})
    return out


def test_fuzz_clip_loader() -> None:
    inputs = _inputs()
    assert len(inputs) >= 500
    t0 = time.perf_counter()
    outcomes = []
    for i in range(0, len(inputs), BATCH):
        outcomes += _run_batch(inputs[i : i + BATCH])
    wall = time.perf_counter() - t0
    counts = collections.Counter(o["kind"] for o in outcomes)
    slowest = max(o["s"] or 0 for o in outcomes)
    print(f"\nfuzz: {len(inputs)} inputs in {wall:.1f} s: {dict(counts)}; slowest input {slowest:.2f} s")
    bad = [(i, o) for i, o in enumerate(outcomes) if o["kind"] not in ("ok", "error")]
    assert not bad, [(i, o, inputs[i][:80]) for i, o in bad[:5]]
    assert len(outcomes) == len(inputs)
    assert counts["ok"] > 0 and counts["error"] > 0


def test_fuzz_inputs_are_reproducible() -> None:
    """The seeded inputs are the same on every run (a failure's index names one input)."""
    assert _inputs() == _inputs()


def test_a_crash_is_pinned_to_its_input() -> None:
    """The re-run path: a batch whose child dies is split, and only the crashing input fails."""
    outcomes = _run_batch([b"fine", b"CRASH", b"fine"], _crash_on_marker)
    assert [o["kind"] for o in outcomes] == ["ok", "child-failed", "ok"]
    assert "the parser process died (SIGSEGV)" in outcomes[1]["detail"]


def _crash_on_marker(blobs: list[bytes], per_input_s: float) -> bytes:
    for b in blobs:
        if b == b"CRASH":
            ctypes.string_at(0)  # a real segfault, in the child
    return json.dumps([{"kind": "ok", "detail": "", "s": 0.0} for _ in blobs]).encode()
