"""A pre-pass over a pickle's opcodes that bounds what unpickling it can cost, before it runs.

CPython's C unpickler allocates first and reads second in a few places: BINBYTES/BINBYTES8/
BYTEARRAY8 allocate their declared length, and PUT/LONG_BINPUT grow the memo array to the index
they name. A few bytes can therefore ask for gigabytes. This scan walks the opcodes (building
nothing) and refuses a length beyond the bytes that remain, a memo index above the limit, an
unknown opcode or a missing STOP; it also sums an estimate of the memory the unpickled objects
take (within 0.8-1.6x of tracemalloc's peak for lists, floats, references and marks; more for
dicts and strings), so a file of millions of tiny lists is refused before any is built.

Speed: a clip is rows of BINFLOATs. A run of them is checked with one strided slice (every 9th
byte is the opcode `G`), other cheap opcodes in runs by one regular expression, so the scan costs
about what the unpickling costs.
"""

from __future__ import annotations

import re
import struct
from typing import Any

import numpy as np

from mimickit.util.limits import ClipLimits, env_var_for

# Runs of opcodes that each push at most one reference per 2 input bytes: BINFLOAT, BININT1,
# BINGET, LONG_BINGET, BINPUT, LONG_BINPUT with an index below 2**20, APPEND(S), SETITEM(S), POP.
# A reference costs 8 bytes on the stack and 8 more, plus over-allocation, in the list it lands
# in: 12 bytes per input byte bounds them (measured with tracemalloc: 200k BINGETs of one list
# peak at 25 bytes each). BINFLOAT runs outside this regex cost their float objects instead.
_CHEAP_RUN = re.compile(rb"(?:G.{8}|K.|h.|j.{4}|q.|r..[\x00-\x0f]\x00|[aesu0])*", re.DOTALL)
_FLOAT_RUN = re.compile(rb"(?:G.{8})*", re.DOTALL)
_CHEAP_BYTES_COST = 12
# The highest memo index allowed (the run above admits exactly the LONG_BINPUTs below it): the C
# unpickler grows its memo array to twice the index, so this bounds it to 16 MB. A real clip uses
# about one index per frame.
MAX_MEMO_INDEX = (1 << 20) - 1

_G = 0x47
_STOP = 0x2E
_LONG_BINPUT = 0x72
_FRAME = 0x95
_PUT = 0x70
# Argument kinds, per opcode byte: n >= 0 is a fixed n-byte argument; the negative ones below.
_LINE, _LINE2, _COUNTED, _EXT, _INVALID = -1, -2, -3, -4, -5
_KIND = [_INVALID] * 256
_COST = [0] * 256  # estimated bytes of what the opcode creates
_COUNT_FORMAT: dict[int, tuple[str, int]] = {}  # counted opcodes: struct format of the length, its width
_OBJ = 88  # a small list or tuple (with its GC header), or an object, plus its reference


def _op(codes: str, kind: int, cost: int) -> None:
    for c in codes:
        _KIND[ord(c)] = kind
        _COST[ord(c)] = cost


_op("N\x88\x892", 0, 24)  # NONE, NEWTRUE, NEWFALSE, DUP: one reference, on the stack then in a list
_op("(", 0, 16)  # MARK: an 8-byte mark, its array grown by doubling
_op("aesu01\x90.\x98", 0, 0)  # APPEND(S), SETITEM(S), POP, POP_MARK, ADDITEMS, STOP, READONLY_BUFFER
_op("]lt)\x85\x86\x87", 0, _OBJ)  # lists and tuples
_op("}d\x8f\x91", 0, 240)  # dicts and sets: a hash table on the first insert
_op(
    "Rbo\x81\x92\x93\x94Q\x97", 0, _OBJ
)  # REDUCE, BUILD, OBJ, NEWOBJ(_EX), STACK_GLOBAL, MEMOIZE, BINPERSID, NEXT_BUFFER
_op("G", 8, 40)
_op("Khq", 1, 8)
_op("jr", 4, 8)
_op("MJ", 2, 128)  # ints beyond the small-int cache (maybe dict keys)
_KIND[ord("J")] = 4
_op("\x80", 1, 0)  # PROTO
_op("\x95", 8, 0)  # FRAME: its length is checked against the remaining bytes
_op("\x82", 1, 0)  # EXT1/2/4: the extension registry, never used by a clip
_op("\x83", 2, 0)
_op("\x84", 4, 0)
for _c in "\x82\x83\x84":
    _KIND[ord(_c)] = _EXT
_op("IFLgpPVS", _LINE, 128)  # INT, FLOAT, LONG, GET, PUT, PERSID, UNICODE, STRING: a text line
_op("ci", _LINE2, _OBJ)  # GLOBAL, INST: module and name lines
for _c, _fmt, _cost in (
    ("U", "<B", 128),  # SHORT_BINSTRING
    ("C", "<B", 64),  # SHORT_BINBYTES
    ("\x8c", "<B", 128),  # SHORT_BINUNICODE
    ("\x8a", "<B", 64),  # LONG1
    ("T", "<i", 128),  # BINSTRING (signed length)
    ("B", "<I", 64),  # BINBYTES
    ("X", "<I", 128),  # BINUNICODE
    ("\x8b", "<i", 64),  # LONG4 (signed length)
    ("\x8d", "<Q", 128),  # BINUNICODE8
    ("\x8e", "<Q", 64),  # BINBYTES8
    ("\x96", "<Q", 64),  # BYTEARRAY8
):
    _op(_c, _COUNTED, _cost)
    _COUNT_FORMAT[ord(_c)] = (_fmt, struct.calcsize(_fmt))
# Runs of argument-less opcodes of one cost (STOP excluded), keyed by that cost.
_BYTE = [bytes([i]) for i in range(256)]
_ONE_BYTE_RUNS = {
    cost: re.compile(
        b"["
        + b"".join(re.escape(_BYTE[i]) for i in range(256) if _KIND[i] == 0 and _COST[i] == cost and i != _STOP)
        + b"]*"
    )
    for cost in {_COST[i] for i in range(256) if _KIND[i] == 0}
}
# A decoded string may take 4 bytes per encoded byte (one astral character widens the whole string).
_STRING_OPS = frozenset(ord(c) for c in "U\x8cTX\x8dSV")


class PickleScanError(ValueError):
    """The pickle is malformed or asks for more than the limits allow."""


class PickleScanLimitError(PickleScanError):
    """The pickle is over the memory estimate's limit."""


def scan_pickle(data: bytes, start: int = 0, limits: ClipLimits | None = None) -> tuple[int, int]:
    """(end, estimated bytes) of the pickle that starts at `start`; `end` is just past its STOP.

    Raises PickleScanError on a truncated or malformed opcode stream or a limit exceeded.
    """
    limits = limits or ClipLimits()
    n = len(data)
    pos, est, run = start, 0, 1
    cheap, floats, kinds, costs = _CHEAP_RUN.match, _FLOAT_RUN.match, _KIND, _COST
    while pos < n:
        code = data[pos]
        if code == _G:
            pos, est, run = _float_rows(data, pos, est, run, floats)
            continue
        kind = kinds[code]
        if kind == 0:
            if code == _STOP:
                _check_budget(est, limits)
                return pos + 1, est
            if data[pos + 1 : pos + 2] == _BYTE[code]:  # a run of one-byte opcodes (a list bomb): one match
                end = _ONE_BYTE_RUNS[costs[code]].match(data, pos).end()
                est += costs[code] * (end - pos)
                pos = end
            else:
                pos += 1
                est += costs[code]
            continue
        if kind > 0:  # cheap fixed-length ones, in a run
            end = cheap(data, pos).end()
            if end > pos:
                est += (end - pos) * _CHEAP_BYTES_COST
                pos = end
                continue
        pos, cost = _special(data, pos, code, kind)
        est += cost
    raise PickleScanError(f"the pickle ends at byte {n} without its STOP opcode (truncated file)")


def _float_rows(data: bytes, pos: int, est: int, run: int, floats: Any) -> tuple[int, int, int]:
    """Rows of BINFLOATs from `pos`, as a clip writes them, in one loop: (position, estimate, row length).

    A run of floats is checked with one strided compare (every 9th byte is `G`), trying the last
    row's length first. Between rows a clip has APPENDS, EMPTY_LIST, BINPUT or LONG_BINPUT (index
    below 2**20, as the cheap run admits), MARK: that boundary is checked here too, so a row costs
    one trip round this loop instead of five round the main one; and once rows of one length are
    seen, `_uniform_rows` checks the next ones all at once.
    """
    row_cost = _OBJ + 16  # the row's list and its MARK
    try_uniform = True
    while True:
        after = pos + 9 * run
        if data[pos:after:9] != b"G" * run or data[after : after + 1] == b"G":
            found = (floats(data, pos).end() - pos) // 9
            if found == 0 and data[pos : pos + 1] == b"G":
                raise PickleScanError(f"opcode 0x47 at byte {pos} is cut off (truncated file)")
            if found == 0:  # not a float here (a block of rows ended on a broken row): the main loop decides
                return pos, est, run
            run = found
            after = pos + 9 * run
        est += 40 * run  # a float object, its reference on the stack and in its list
        pos = after
        head = data[pos : pos + 9]
        if head[:3] == b"e]q" and head[4:6] == b"(G":
            memo = 2
        elif head[:3] == b"e]r" and head[5:6] <= b"\x0f" and head[6:9] == b"\x00(G":
            memo = 5
        else:
            return pos, est, run
        pos += 3 + memo
        est += row_cost + 12 * memo
        if try_uniform:
            rows = _uniform_rows(data, pos, run, memo)
            pos += rows * (9 * run + 3 + memo)
            est += rows * (40 * run + row_cost + 12 * memo)
            try_uniform = rows > 0


def _uniform_rows(data: bytes, pos: int, width: int, memo: int) -> int:
    """How many rows from `pos` are exactly `width` BINFLOATs, APPENDS, EMPTY_LIST, a memo put of
    `memo` bytes (BINPUT, or LONG_BINPUT below 2**20), MARK: checked for all of them at once with
    numpy (a clip's rows up to its 256th look so, and the ones after)."""
    stride = 9 * width + 3 + memo
    count = (len(data) - pos) // stride
    if count < 16:
        return 0
    rows = np.frombuffer(data, np.uint8, count * stride, pos).reshape(count, stride)
    tail = rows[:, 9 * width :]
    ok = (rows[:, : 9 * width : 9] == _G).all(axis=1) & (tail[:, 0] == 0x65) & (tail[:, 1] == 0x5D)
    if memo == 2:
        ok &= (tail[:, 2] == 0x71) & (tail[:, 4] == 0x28)
    else:
        ok &= (tail[:, 2] == _LONG_BINPUT) & (tail[:, 5] <= 0x0F) & (tail[:, 6] == 0) & (tail[:, 7] == 0x28)
    return count if ok.all() else int(np.argmin(ok))


def _special(data: bytes, pos: int, code: int, kind: int) -> tuple[int, int]:
    """(position after, cost) of one opcode outside the fast paths; checks its argument."""
    n = len(data)
    arg_at = pos + 1
    cost = _COST[code]
    if kind == _INVALID:
        raise PickleScanError(f"invalid pickle opcode 0x{code:02x} at byte {pos}")
    if kind == _EXT:
        raise PickleScanError(f"pickle extension codes (opcode 0x{code:02x} at byte {pos}) are not allowed")
    if kind >= 0:
        end = arg_at + kind
        if end > n:
            raise PickleScanError(f"opcode 0x{code:02x} at byte {pos} is cut off (truncated file)")
        if code == _LONG_BINPUT:
            _check_memo(struct.unpack_from("<I", data, arg_at)[0], pos)
        elif code == _FRAME and struct.unpack_from("<Q", data, arg_at)[0] > n - end:
            raise PickleScanError(f"a frame at byte {pos} declares more bytes than the {n - end} that remain")
        return end, cost
    if kind == _COUNTED:
        fmt, width = _COUNT_FORMAT[code]
        if arg_at + width > n:
            raise PickleScanError(f"opcode 0x{code:02x} at byte {pos} is cut off (truncated file)")
        (length,) = struct.unpack_from(fmt, data, arg_at)
        body = arg_at + width
        if length < 0 or length > n - body:
            raise PickleScanError(f"opcode 0x{code:02x} at byte {pos} declares {length} bytes but {n - body} remain")
        return body + length, cost + (4 * length if code in _STRING_OPS else length)
    end = arg_at
    for _ in range(2 if kind == _LINE2 else 1):
        nl = data.find(b"\n", end)
        if nl < 0:
            raise PickleScanError(f"opcode 0x{code:02x} at byte {pos} has no end of line (truncated file)")
        end = nl + 1
    if code == _PUT:
        _check_memo(_line_int(data, arg_at, end - 1), pos)
    return end, cost + (4 if code in _STRING_OPS else 1) * (end - arg_at)


def _check_memo(index: int, at: int) -> None:
    if index > MAX_MEMO_INDEX:
        raise PickleScanError(f"memo index {index} at byte {at} is over the limit of {MAX_MEMO_INDEX}")


def _check_budget(est: int, limits: ClipLimits) -> None:
    if est > limits.max_parse_bytes:
        var = env_var_for("max_parse_mb")
        raise PickleScanLimitError(
            f"unpickling it would need more than {limits.max_parse_mb:g} MB (set {var} to allow more)"
        )


def _line_int(data: bytes, start: int, end: int) -> int:
    text = data[start:end].strip()
    if not text.isdigit() or len(text) > 12:
        raise PickleScanError(f"memo index {text[:20]!r} at byte {start - 1} is not a small whole number")
    return int(text)
