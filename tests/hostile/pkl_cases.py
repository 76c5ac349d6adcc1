# ruff: noqa: E501 - the case tables read best one case a line
"""Crafted `.pkl` clips for the hostile-input suite and the fuzz test.

Each case is `Case(id, data, outcome, match)`: `outcome` "error" means `load_motion` must raise one
MimicKitError line matching `match`; "invalid" means it loads but `validate_motion` reports a
problem matching `match`; "ok" means it loads and validates (with `frames`, when given, the exact
values it must hold: a view that read other memory would not). Built from opcodes by hand where
pickle itself would never write them.
"""

from __future__ import annotations

import io
import math
import pickle
import struct
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from mimickit.util.limits import ClipLimits

TORCH_MAGIC = 0x1950A86A20F9469CFC6C
W = 34  # the humanoid's frame width


@dataclass(frozen=True)
class Case:
    id: str
    data: bytes
    outcome: str  # "error" | "invalid" | "ok"
    match: str = ""
    frames: np.ndarray | None = None
    limits: ClipLimits | None = None
    crashed_before: bool = False  # segfaulted or read heap memory before the fix: also run through the CLI


# --- opcode building blocks ------------------------------------------------------------------------


def v(x: object, protocol: int = 3) -> bytes:
    """The opcodes that push `x` (no PROTO, no STOP, no memo: fragments can be spliced)."""
    buf = io.BytesIO()
    p = pickle.Pickler(buf, protocol=protocol)
    p.fast = True
    p.dump(x)
    out = buf.getvalue()
    return out[2:-1] if protocol >= 2 else out[:-1]


def glob(module: str, name: str) -> bytes:
    return b"c" + module.encode() + b"\n" + name.encode() + b"\n"


def clip(fps_ops: bytes | None = None, frames_ops: bytes | None = None, loop_ops: bytes | None = None) -> bytes:
    """A clip dict whose values are the given opcodes (defaults: loop 0, fps 30, 3 plain frames)."""
    return (
        b"\x80\x03}("
        + v("loop_mode")
        + (loop_ops if loop_ops is not None else v(0))
        + v("fps")
        + (fps_ops if fps_ops is not None else v(30))
        + v("frames")
        + (frames_ops if frames_ops is not None else v(plain_frames(3).tolist()))
        + b"u."
    )


def plain_frames(t: int, w: int = W) -> np.ndarray:
    return (np.arange(t * w, dtype=np.float64).reshape(t, w) * 0.25 - 3.0).astype(np.float32)


def dumps_clip(frames: object, fps: object = 30, loop_mode: object = 0, protocol: int = 3, **extra: object) -> bytes:
    return pickle.dumps({"loop_mode": loop_mode, "fps": fps, "frames": frames, **extra}, protocol=protocol)


def storage_bytes(
    values: bytes,
    numel: int,
    *,
    storage: str = "FloatStorage",
    key: str = "k0",
    magic: int = TORCH_MAGIC,
    little_endian: bool = True,
    keys: list | None = None,
    trailing: bytes = b"",
) -> bytes:
    """torch's legacy serialization of one storage, as `torch.storage._load_from_bytes` reads it."""
    info = {"protocol_version": 1001, "little_endian": little_endian, "type_sizes": {"short": 2, "int": 4, "long": 4}}
    head = pickle.dumps(magic, protocol=2) + pickle.dumps(1001, protocol=2) + pickle.dumps(info, protocol=2)
    record = (
        b"\x80\x02(" + v("storage", 2) + glob("torch", storage) + v(key, 2) + v("cpu", 2) + v(numel, 2) + b"Nt" + b"Q."
    )
    keys_pickle = pickle.dumps(keys if keys is not None else [key], protocol=2)
    return head + record + keys_pickle + struct.pack("<q", numel) + values + trailing


def tensor(storage: bytes, offset: object, size: object, stride: object, storage_ops: bytes | None = None) -> bytes:
    """The opcodes of `torch._utils._rebuild_tensor_v2(_load_from_bytes(storage), offset, size, stride, ...)`."""
    load = storage_ops if storage_ops is not None else glob("torch.storage", "_load_from_bytes") + v(storage) + b"\x85R"
    return (
        glob("torch._utils", "_rebuild_tensor_v2")
        + b"("
        + load
        + v(offset)
        + v(size)
        + v(stride)
        + b"\x89"
        + glob("collections", "OrderedDict")
        + b")R"
        + b"tR"
    )


def f32_storage(values: np.ndarray) -> bytes:
    flat = np.ascontiguousarray(values, dtype="<f4").ravel()
    return storage_bytes(flat.tobytes(), flat.size)


def ndarray_ops(shape: object, dtype_args: tuple, dtype_state: tuple, raw: object, fortran: object = False) -> bytes:
    """numpy's pickling of an array (`_reconstruct` + BUILD) with every field chosen by the caller."""
    dtype = glob("numpy", "dtype") + v(dtype_args) + b"R" + v(dtype_state) + b"b"
    return (
        glob("numpy.core.multiarray", "_reconstruct")
        + glob("numpy", "ndarray")
        + v((0,))
        + v(b"b")
        + b"\x87R"
        + b"("
        + v(1)
        + v(shape)
        + dtype
        + v(fortran)
        + v(raw)
        + b"tb"
    )


F8_STATE = (3, "<", None, None, None, -1, -1, 0)
F8_DTYPE = glob("numpy", "dtype") + v(("f8", False, True)) + b"R" + v(F8_STATE) + b"b"


def reconstruct_ops(subtype_ops: bytes) -> bytes:
    return glob("numpy.core.multiarray", "_reconstruct") + b"(" + subtype_ops + v((0,)) + v(b"b") + b"tR"


def frombuffer_ops(raw: bytes, shape: tuple, order: str = "C") -> bytes:
    """numpy's protocol-5 pickling of an array: `_frombuffer(buffer, dtype, shape, order)`."""
    return glob("numpy._core.numeric", "_frombuffer") + b"(" + v(raw) + F8_DTYPE + v(shape) + v(order) + b"tR"


def call_global(module: str, name: str, *args: object) -> bytes:
    return glob(module, name) + v(tuple(args)) + b"R"


def shared_nested(depth: int, fan: int) -> object:
    """`depth` levels of lists, each `fan` references to the same list below: tiny pickled, fan**depth expanded."""
    x: object = [0.5] * fan
    for _ in range(depth - 1):
        x = [x] * fan
    return x


# --- the cases ------------------------------------------------------------------------------------


def _tensor_cases() -> list[Case]:
    one = f32_storage(np.array([30.0]))
    frames34 = plain_frames(1)  # 34 floats
    st34 = f32_storage(frames34)
    two = plain_frames(2)
    st68 = f32_storage(two)
    return [
        Case("err-tensor-stride-2pow40", clip(tensor(one, 0, (2,), (2**40,))), "error", "reaches element", crashed_before=True),
        Case("err-tensor-negative-stride", clip(tensor(one, 0, (2,), (-1,))), "error", "stride", crashed_before=True),
        Case("err-tensor-negative-stride-from-end", clip(frames_ops=tensor(st68, 67, (2, 34), (-34, -1))), "error", "stride", crashed_before=True),
        Case("err-tensor-64x34-view-over-34-floats", clip(frames_ops=tensor(st34, 0, (64, 34), (34, 1))), "error", "reaches element 2175 of a storage of 34", crashed_before=True),
        Case("err-tensor-size-stride-length-mismatch", clip(frames_ops=tensor(st68, 0, (2, 34), (1,))), "error", "one length", crashed_before=True),
        Case("err-tensor-negative-offset", clip(tensor(one, -1, (), ())), "error", "offset", crashed_before=True),
        Case("err-tensor-offset-past-storage", clip(tensor(one, 5, (), ())), "error", "offset", crashed_before=True),
        Case("err-tensor-offset-plus-extent-one-past", clip(frames_ops=tensor(st34, 1, (1, 34), (34, 1))), "error", "reaches element 34", crashed_before=True),
        Case("err-tensor-broadcast-10pow12-elements", clip(frames_ops=tensor(one, 0, (10**6, 10**6), (0, 0))), "error", "elements, over the limit"),
        Case("err-tensor-size-10pow400", clip(frames_ops=tensor(one, 0, (10**400, 34), (0, 0))), "error", "elements, over the limit"),
        Case("err-tensor-negative-size", clip(frames_ops=tensor(st34, 0, (-1, 34), (0, 1))), "error", "size >= 0"),
        Case("err-tensor-float-stride", clip(frames_ops=tensor(st34, 0, (1, 34), (34, 1.5))), "error", "stride"),
        Case("err-tensor-bool-offset", clip(tensor(one, True, (), ())), "error", "offset"),
        Case("err-tensor-20-dims", clip(tensor(one, 0, (1,) * 20, (0,) * 20)), "error", "at most 8"),
        Case("err-tensor-size-is-a-list", clip(tensor(one, 0, [1], [1])), "error", "tuples"),
        Case("err-tensor-storage-is-a-list", clip(tensor(one, 0, (), (), storage_ops=v([1.0]))), "error", "from a storage"),
        Case("err-storage-numel-over-data", clip(tensor(storage_bytes(b"\0" * 4, 10**6), 0, (), ())), "error", "declares 1000000 elements"),
        Case("err-storage-numel-negative", clip(tensor(storage_bytes(b"\0" * 4, -5), 0, (), ())), "error", "declares -5 elements"),
        Case("err-storage-numel-2pow62", clip(tensor(storage_bytes(b"\0" * 4, 2**62), 0, (), ())), "error", "declares"),
        Case("err-storage-bad-magic", clip(tensor(storage_bytes(b"\0" * 4, 1, magic=12345), 0, (), ())), "error", "magic number"),
        Case("err-storage-big-endian", clip(tensor(storage_bytes(b"\0" * 4, 1, little_endian=False), 0, (), ())), "error", "little-endian"),
        Case("err-storage-trailing-bytes", clip(tensor(storage_bytes(b"\0" * 4, 1, trailing=b"xyz"), 0, (), ())), "error", "unexpected bytes"),
        Case("err-storage-complex-type", clip(tensor(storage_bytes(b"\0" * 8, 1, storage="ComplexFloatStorage"), 0, (), ())), "error", "refused to load global 'torch.ComplexFloatStorage'"),
        Case("err-storage-keys-mismatch", clip(tensor(storage_bytes(b"\0" * 4, 1, keys=["other"]), 0, (), ())), "error", "keys do not match"),
        Case("err-storage-not-bytes", clip(tensor(b"", 0, (), (), storage_ops=glob("torch.storage", "_load_from_bytes") + v(("abc",)) + b"R")), "error", "needs bytes"),
        Case("ok-tensor-fps-0d", clip(tensor(one, 0, (), ())), "ok"),
        Case("ok-tensor-frames-2x34", clip(frames_ops=tensor(st68, 0, (2, 34), (34, 1))), "ok", frames=two),
        Case("ok-tensor-frames-transposed-view", clip(frames_ops=tensor(f32_storage(two.T), 0, (2, 34), (1, 2))), "ok", frames=two),
        Case("ok-tensor-frames-offset-exact-fit", clip(frames_ops=tensor(f32_storage(plain_frames(3)), 34, (2, 34), (34, 1))), "ok", frames=plain_frames(3)[1:]),
        Case("ok-tensor-frames-repeated-row-stride-0", clip(frames_ops=tensor(st34, 0, (3, 34), (0, 1))), "ok", frames=np.repeat(frames34, 3, 0)),
    ]  # fmt: skip


def _numpy_cases() -> list[Case]:
    f = plain_frames(3)
    raw8 = f.astype("<f8").tobytes()
    good = ndarray_ops((3, W), ("f8", False, True), F8_STATE, raw8)
    return [
        Case("err-numpy-shape-bigger-than-data", clip(frames_ops=ndarray_ops((100, W), ("f8", False, True), F8_STATE, raw8)), "error", "needs 27200 bytes, the file holds 816"),
        Case("err-numpy-shape-2pow62", clip(frames_ops=ndarray_ops((2**62, 4), ("f8", False, True), F8_STATE, raw8)), "error", "over the limit"),
        Case("err-numpy-negative-shape", clip(frames_ops=ndarray_ops((-3, W), ("f8", False, True), F8_STATE, raw8)), "error", "size >= 0"),
        Case("err-numpy-object-dtype", clip(frames_ops=ndarray_ops((3,), ("O8", False, True), (3, "|", None, None, None, -1, -1, 63), [1, 2, 3])), "error", "dtype 'O8' is not allowed"),
        Case("err-numpy-object-dtype-real-pickle", dumps_clip(np.array([[1.0] * W, [None] * W], dtype=object)), "error", "dtype 'O8' is not allowed"),
        Case("err-numpy-complex-frames", dumps_clip(f.astype(np.complex64)), "error", "dtype 'c8' is not allowed"),
        Case("err-numpy-complex-fps-scalar", dumps_clip(f.tolist(), fps=np.complex128(30)), "error", "dtype 'c16' is not allowed"),
        Case("err-numpy-structured-dtype", dumps_clip(np.zeros(3, dtype=[("a", "f4"), ("b", "f8")])), "error", "not allowed"),
        Case("err-numpy-string-dtype", dumps_clip(np.array([["1.0"] * W] * 2)), "error", "dtype 'U3' is not allowed"),
        Case("err-numpy-dtype-state-with-flags", clip(frames_ops=ndarray_ops((3, W), ("f8", False, True), (3, "<", None, None, None, -1, -1, 63), raw8)), "error", "plain number type"),
        Case("err-numpy-dtype-state-elsize", clip(frames_ops=ndarray_ops((3, W), ("f8", False, True), (3, "<", None, None, None, 1, 1, 0), raw8)), "error", "plain number type"),
        Case("err-numpy-reconstruct-other-class", clip(frames_ops=reconstruct_ops(glob("collections", "OrderedDict"))), "error", "_reconstruct called with"),
        Case("err-numpy-array-state-not-tuple", clip(frames_ops=reconstruct_ops(glob("numpy", "ndarray")) + v({"shape": 3}) + b"b"), "error", "state is not"),
        Case("err-numpy-array-without-state", clip(frames_ops=reconstruct_ops(glob("numpy", "ndarray"))), "error", "has no state"),
        Case("err-numpy-ndarray-called-directly", clip(frames_ops=glob("numpy", "ndarray") + v(((2,), "f8")) + b"R"), "error", "corrupt pickle"),
        Case("err-numpy-scalar-wrong-length", clip(glob("numpy.core.multiarray", "scalar") + F8_DTYPE + v(b"\0" * 3) + b"\x86R"), "error", "needs 8 bytes"),
        Case("ok-numpy-scalar-fps-crafted", clip(glob("numpy._core.multiarray", "scalar") + F8_DTYPE + v(struct.pack("<d", 30.0)) + b"\x86R"), "ok"),
        Case("err-numpy-frombuffer-short", clip(frames_ops=frombuffer_ops(raw8[:-8], (3, W))), "error", "does not fit its bytes|needs 816 bytes"),
        Case("err-numpy-frombuffer-order-k", clip(frames_ops=frombuffer_ops(raw8, (3, W), order="K")), "error", "order 'C' or 'F'"),
        Case("ok-numpy-frombuffer-crafted", clip(frames_ops=frombuffer_ops(raw8, (3, W))), "ok", frames=f),
        Case("ok-numpy-frames-float64", clip(frames_ops=good), "ok", frames=f),
        Case("ok-numpy-frames-protocol2", dumps_clip(f.astype(np.float64), fps=np.float64(30), protocol=2), "ok", frames=f),
        Case("ok-numpy-frames-protocol4", dumps_clip(f, fps=np.float32(30), protocol=4), "ok", frames=f),
        Case("ok-numpy-frames-protocol5", dumps_clip(f, fps=np.int64(30), protocol=5), "ok", frames=f),
        Case("ok-numpy-frames-big-endian", dumps_clip(f.astype(">f8")), "ok", frames=f),
        Case("ok-numpy-frames-fortran-order", dumps_clip(np.asfortranarray(f)), "ok", frames=f),
        Case("ok-numpy-frames-int16", dumps_clip(np.arange(3 * W, dtype=np.int16).reshape(3, W)), "ok", frames=np.arange(3 * W, dtype=np.float32).reshape(3, W)),
        Case("ok-numpy-rows-list-of-arrays", dumps_clip(list(f)), "ok", frames=f),
    ]  # fmt: skip


def _structure_cases() -> list[Case]:
    f = plain_frames(3)
    rows = f.tolist()
    row = rows[0]
    nan_rows = [[math.nan] * W for _ in range(3)]
    some_nan = [r[:] for r in rows]
    some_nan[1][7] = math.nan
    inf_rows = [r[:] for r in rows]
    inf_rows[2][0] = math.inf
    return [
        Case("err-shared-nested-lists-4kb-2-levels", dumps_clip(shared_nested(3, 300)), "error", r"frames\[0\]\[0\] is a list"),
        Case("err-shared-nested-lists-4-levels", dumps_clip(shared_nested(4, 100)), "error", "frames must be 2-D"),
        Case("err-shared-nested-lists-6-levels-as-row", dumps_clip([shared_nested(6, 40)] * 2), "error", "frames must be 2-D"),
        Case("err-2000000-frames-4mb", dumps_clip([row] * 2_000_000), "error", "2000000 frames is over the limit of 100000 .set MIMICKIT_MAX_FRAMES"),
        Case("err-frames-over-a-lowered-limit", dumps_clip(rows), "error", "3 frames is over the limit of 2", limits=ClipLimits(max_frames=2)),
        Case("err-width-over-limit", dumps_clip([[0.0] * 513] * 2), "error", "513 values a frame is over the limit of 512"),
        Case("err-values-over-limit", dumps_clip([row] * 100), "error", "over the limit of 1000 values", limits=ClipLimits(max_values=1000)),
        Case("err-int-10pow400-in-frames", dumps_clip([[10**400] + row[1:]] + rows[1:]), "error", r"frames\[0\]\[0\] is an integer too large for a float"),
        Case("err-int-10pow400-fps", dumps_clip(rows, fps=10**400), "error", "fps must be a frame rate, got an integer of 1329 bits"),
        Case("err-int-10pow400-loop-mode", dumps_clip(rows, loop_mode=10**400), "error", "loop_mode must be 0 .clamp. or 1 .wrap., got an integer of"),
        Case("err-all-none-frames", dumps_clip([[None] * W] * 3), "error", r"frames\[0\]\[0\] is None, not a number; columns \[0, 1,"),
        Case("err-none-column", dumps_clip([r[:9] + [None] + r[10:] for r in rows]), "error", r"frames\[0\]\[9\] is None.*columns \[9\] are None in every frame"),
        Case("err-complex-frames", dumps_clip([[complex(1, 2)] * W] * 2), "error", "complex numbers are not allowed .a clip holds real numbers only."),
        Case("err-string-frames", dumps_clip([["0.5"] * W] * 2), "error", "is a str, not a number"),
        Case("err-bytes-in-frames", dumps_clip([[b"x"] * W] * 2), "error", "not a number"),
        Case("err-ragged-frames", dumps_clip([row, row[:-1]]), "error", "equal-length rows"),
        Case("err-empty-frames", dumps_clip([]), "error", "frames is empty"),
        Case("err-width-5", dumps_clip([[0.0] * 5] * 3), "error", "got 5 values a frame"),
        Case("err-frames-a-dict", dumps_clip({"a": 1}), "error", "frames must be a list of frames, got dict"),
        Case("err-frames-a-row-is-a-number", dumps_clip([1.0, 2.0]), "error", r"frames\[0\] must be a list of numbers, got 1.0"),
        Case("err-frames-contains-itself", _self_containing_frames(), "error", "frames"),
        Case("err-deeply-nested-100000", b"\x80\x03}(" + v("loop_mode") + v(0) + v("fps") + v(30) + v("frames") + b"]" * 100_000 + b"a" * 99_999 + b"u.", "error", "values a frame"),
        Case("err-not-a-dict", pickle.dumps([1, 2, 3]), "error", "expected a dict"),
        Case("err-missing-keys", pickle.dumps({"fps": 30}), "error", "missing key.s. loop_mode, frames"),
        Case("err-loop-mode-2", dumps_clip(rows, loop_mode=2), "error", "loop_mode must be 0"),
        Case("err-loop-mode-string", dumps_clip(rows, loop_mode="wrap"), "error", "loop_mode must be a real number, got str"),
        Case("err-fps-1e-300", dumps_clip(rows, fps=1e-300), "error", "fps must be between 0.001 and 10000 frames a second, got 1e-300"),
        Case("err-fps-nan", dumps_clip(rows, fps=math.nan), "error", "got nan"),
        Case("err-fps-inf", dumps_clip(rows, fps=math.inf), "error", "got inf"),
        Case("err-fps-zero", dumps_clip(rows, fps=0), "error", "got 0.0"),
        Case("err-fps-negative", dumps_clip(rows, fps=-30), "error", "got -30.0"),
        Case("err-fps-1e5", dumps_clip(rows, fps=1e5), "error", "got 100000.0"),
        Case("err-fps-complex", dumps_clip(rows, fps=complex(30, 1)), "error", "complex numbers are not allowed"),
        Case("err-fps-list", dumps_clip(rows, fps=[30, 60]), "error", "fps must be a real number, got list"),
        Case("err-fps-bool", dumps_clip(rows, fps=True), "error", "fps must be a real number, got bool"),
        Case("err-validate-all-nan", dumps_clip(nan_rows), "invalid", r"columns \[0, 1, .*33\] are NaN in every frame"),
        Case("err-validate-one-nan-value", dumps_clip(some_nan), "invalid", r"1 non-finite values .NaN or infinite. in columns \[7\]"),
        Case("err-validate-inf-value", dumps_clip(inf_rows), "invalid", r"non-finite values .* in columns \[0\]"),
        Case("err-validate-one-frame", dumps_clip([row]), "invalid", "only 1 frame"),
        Case("ok-shared-rows-via-memo", dumps_clip([row] * 500), "ok", frames=np.repeat(f[:1], 500, 0)),
        Case("ok-tuple-frames", dumps_clip(tuple(tuple(r) for r in rows)), "ok", frames=f),
        Case("ok-int-frames", dumps_clip([[int(x) for x in range(W)]] * 2), "ok", frames=np.tile(np.arange(W, dtype=np.float32), (2, 1))),
        Case("ok-ordered-dict-clip", pickle.dumps(OrderedDict(loop_mode=1, fps=60.0, frames=rows)), "ok", frames=f),
        Case("ok-extra-key-ignored", dumps_clip(rows, name="squat"), "ok", frames=f),
        Case("ok-frames-at-the-frame-limit", dumps_clip(rows), "ok", frames=f, limits=ClipLimits(max_frames=3)),
    ] + [Case(f"ok-plain-protocol-{p}", dumps_clip(rows, protocol=p), "ok", frames=f) for p in range(6)]  # fmt: skip


def _self_containing_frames() -> bytes:
    frames: list = []
    frames.append(frames)
    frames.append(frames)
    return dumps_clip(frames)


def _opcode_cases() -> list[Case]:
    return [
        Case("err-memo-long-binput-2pow31", b"\x80\x03]r\x00\x00\x00\x80.", "error", "memo index 2147483648 at byte 3 is over the limit"),
        Case("err-memo-long-binput-2pow20", b"\x80\x03]r\x00\x00\x10\x00.", "error", "memo index 1048576"),
        Case("err-memo-put-text-huge", b"(lp99999999999\n.", "error", "memo index 99999999999"),
        Case("err-memo-put-text-10pow400", b"(lp" + b"9" * 400 + b"\n.", "error", "not a small whole number"),
        Case("err-binbytes8-2pow62", b"\x80\x04\x8e" + struct.pack("<Q", 2**62) + b"xx.", "error", "declares 4611686018427387904 bytes but 3 remain"),
        Case("err-binunicode8-2pow40", b"\x80\x04\x8d" + struct.pack("<Q", 2**40) + b"xx.", "error", "declares 1099511627776 bytes"),
        Case("err-bytearray8-2pow50", b"\x80\x05\x96" + struct.pack("<Q", 2**50) + b"xx.", "error", "declares"),
        Case("err-binbytes-2pow31", b"\x80\x03B" + struct.pack("<I", 2**31) + b"xx.", "error", "declares 2147483648 bytes"),
        Case("err-binunicode-over-remaining", b"\x80\x03X" + struct.pack("<I", 100) + b"abc.", "error", "declares 100 bytes but 4 remain"),
        Case("err-binstring-negative-length", b"T" + struct.pack("<i", -5) + b"abc.", "error", "declares -5 bytes"),
        Case("err-long4-2pow30", b"\x80\x03\x8b" + struct.pack("<i", 2**30) + b"\x01.", "error", "declares 1073741824 bytes"),
        Case("err-frame-2pow60", b"\x80\x04\x95" + struct.pack("<Q", 2**60) + b"N.", "error", "a frame at byte 2 declares more bytes"),
        Case("err-list-bomb-over-parse-budget", b"\x80\x03](" + b"]" * 40_000 + b"e.", "error", "would need more than 2 MB .set MIMICKIT_MAX_PARSE_MB", limits=ClipLimits(max_parse_mb=2)),
        Case("err-list-bomb-15mb-default-budget", b"\x80\x03](" + b"]" * 16_000_000 + b"e.", "error", "would need more than 1024 MB"),
        Case("err-mark-bomb", b"\x80\x03" + b"(" * 400_000 + b".", "error", "would need more than 3 MB", limits=ClipLimits(max_parse_mb=3)),
        Case("err-string-bomb-astral", b"\x80\x03X" + struct.pack("<I", 800_004) + b"\xf0\x9f\x98\x80" + b"a" * 800_000 + b".", "error", "would need more than 2 MB", limits=ClipLimits(max_parse_mb=2)),
        Case("err-extension-code", b"\x80\x02\x82\x01.", "error", "extension codes"),
        Case("err-persistent-id", b"\x80\x03X\x01\x00\x00\x00aQ.", "error", "persistent ids are not allowed"),
        Case("err-persistent-id-text", b"Pabc\n.", "error", "persistent ids are not allowed"),
        Case("err-invalid-opcode", b"\x80\x03\xff.", "error", "invalid pickle opcode 0xff at byte 2"),
        Case("err-unsupported-protocol", b"\x80\x09N.", "error", "corrupt pickle"),
        Case("err-stack-underflow", b"\x80\x03a.", "error", "corrupt pickle"),
        Case("err-empty-file", b"", "error", "the file is empty"),
        Case("err-just-proto", b"\x80", "error", "cut off"),
        Case("err-no-stop", b"\x80\x03}", "error", "without its STOP opcode"),
        Case("err-trailing-garbage", dumps_clip(plain_frames(2).tolist()) + b"garbage", "error", "7 unexpected bytes after the pickle's end"),
        Case("err-not-a-pickle-text", b"this is a text file, not a pickle\n", "error", "not a MimicKit clip"),
        Case("err-not-a-pickle-png", b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR", "error", "not a MimicKit clip"),
        Case("err-not-a-pickle-zip", b"PK\x03\x04\x14\x00\x00\x00\x08\x00archive/data.pkl\n\x00", "error", "not a MimicKit clip"),
        Case("err-not-a-pickle-json", b'{"loop_mode": 0, "fps": 30, "frames": []}', "error", "not a MimicKit clip"),
    ]  # fmt: skip


def _global_cases() -> list[Case]:
    cmd = "touch pwned_by_pickle"
    return [
        Case("err-global-os-system", clip(frames_ops=call_global("os", "system", cmd)), "error", "refused to load global 'os.system'"),
        Case("err-global-posix-system", clip(frames_ops=call_global("posix", "system", cmd)), "error", "refused to load global 'posix.system'"),
        Case("err-global-builtins-eval", clip(frames_ops=call_global("builtins", "eval", "__import__('os').system('touch pwned_by_pickle')")), "error", "'builtins.eval'"),
        Case("err-global-builtins-exec", clip(frames_ops=call_global("builtins", "exec", "open('pwned_by_pickle','w')")), "error", "'builtins.exec'"),
        Case("err-global-builtin-eval-py2-name", clip(frames_ops=call_global("__builtin__", "eval", "1")), "error", "'__builtin__.eval'"),
        Case("err-global-builtins-getattr", clip(frames_ops=call_global("builtins", "getattr", 1, "real")), "error", "'builtins.getattr'"),
        Case("err-global-builtins-import", clip(frames_ops=call_global("builtins", "__import__", "os")), "error", "'builtins.__import__'"),
        Case("err-global-subprocess-popen", clip(frames_ops=call_global("subprocess", "Popen", ["touch", "pwned_by_pickle"])), "error", "'subprocess.Popen'"),
        Case("err-global-numpy-as-strided", clip(frames_ops=call_global("numpy.lib.stride_tricks", "as_strided", 1)), "error", "'numpy.lib.stride_tricks.as_strided'"),
        Case("err-global-numpy-load", clip(frames_ops=call_global("numpy", "load", "x.npy")), "error", "'numpy.load'"),
        Case("err-global-numpy-frombuffer", clip(frames_ops=call_global("numpy", "frombuffer", b"\0" * 8)), "error", "'numpy.frombuffer'"),
        Case("err-global-pickle-loads", clip(frames_ops=call_global("pickle", "loads", b"N.")), "error", "'pickle.loads'"),
        Case("err-global-torch-load", clip(frames_ops=call_global("torch", "load", "x.pt")), "error", "'torch.load'"),
        Case("err-global-copyreg-reconstructor", clip(frames_ops=call_global("copyreg", "_reconstructor", 1, 2, 3)), "error", "'copyreg._reconstructor'"),
        Case("err-global-codecs-encode-other-codec", clip(frames_ops=call_global("_codecs", "encode", "x", "rot13")), "error", "only as .str, 'latin1'."),
        Case("err-inst-opcode-os-system", b"(S'" + cmd.encode() + b"'\nios\nsystem\n.", "error", "'os.system'"),
        Case("err-stack-global-os-system", b"\x80\x04\x8c\x02os\x8c\x06system\x93" + v((cmd,)) + b"R.", "error", "'os.system'"),
        Case("err-reduce-on-ordered-dict-with-bomb-arg", clip(frames_ops=glob("collections", "OrderedDict") + v((1.0,)) + b"R"), "error", "corrupt pickle"),
    ]  # fmt: skip


def all_cases() -> list[Case]:
    return _tensor_cases() + _numpy_cases() + _structure_cases() + _opcode_cases() + _global_cases()


# --- the fuzz test's child: classify inputs ------------------------------------------------------


def value_candidates(data: bytes) -> list[np.ndarray]:
    """Every number `data` holds under an encoding a clip can use, as float32: a frame value not
    among them did not come from the file (it came from other memory)."""
    out = []
    for dtype in ("<f8", ">f8", "<f4", ">f4", "<f2", "<i8", "<i4", "<i2", "<u2", "<u4", "i1", "u1", ">i4"):
        size = np.dtype(dtype).itemsize
        for off in range(size):
            n = (len(data) - off) // size
            if n > 0:
                with np.errstate(all="ignore"):
                    out.append(np.frombuffer(data, dtype, n, off).astype(np.float32))
    return out


def frames_from_file(frames: np.ndarray, data: bytes) -> bool:
    """True when every finite frame value is a number encoded somewhere in `data` (or 0/1)."""
    vals = np.unique(frames[np.isfinite(frames)])
    vals = vals[(vals != 0) & (vals != 1)]
    # protocols 0-2 store bytes as a latin-1 string, which the file holds UTF-8 encoded
    latin1 = data.decode("utf-8", "ignore").encode("latin1", "ignore")
    for cand in value_candidates(data) + value_candidates(latin1):
        if vals.size == 0:
            return True
        vals = vals[~np.isin(vals, cand)]
    if vals.size == 0:
        return True
    # protocol 0 writes floats and ints as text
    import re

    text = [float(t) for t in re.findall(rb"-?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?", data)[:100_000]]
    return bool(np.isin(vals, np.array(text, dtype=np.float32)).all()) if text else False


def classify_batch(blobs: list[bytes], per_input_s: float = 5.0) -> bytes:
    """Run in a guarded child by the fuzz test: each input through `motion_from_bytes`, one outcome
    each as JSON: "ok" (a clip whose frames all come from the file), "error" (one MimicKitError
    line), or a failure: "heap" (frames not from the file), "hang" (over `per_input_s`), "memory",
    "multiline" (an error of more than one line) or "exception:<type>" (anything but MimicKitError)."""
    import json
    import signal
    import time

    from mimickit.anim.motion import motion_from_bytes
    from mimickit.util.errors import MimicKitError

    def on_alarm(signum: int, frame: object) -> None:
        raise TimeoutError("per-input alarm")

    signal.signal(signal.SIGALRM, on_alarm)
    out = []
    for blob in blobs:
        t0 = time.perf_counter()
        signal.setitimer(signal.ITIMER_REAL, per_input_s)
        try:
            m = motion_from_bytes(blob, source="fuzz.pkl", sanitize_nan=False)
            kind, detail = ("ok", "") if frames_from_file(m.frames, blob) else ("heap", str(m.frames.shape))
        except MimicKitError as e:
            msg = str(e)
            kind = "memory" if "ran out of memory" in msg else "multiline" if "\n" in msg else "error"
            detail = msg[:300]
        except TimeoutError:
            kind, detail = "hang", f"over {per_input_s:g} s"
        except BaseException as e:  # noqa: BLE001 - the point is to see it
            kind, detail = f"exception:{type(e).__name__}", str(e)[:300]
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
        elapsed = time.perf_counter() - t0
        if elapsed > per_input_s and kind in ("ok", "error"):
            kind, detail = "hang", f"{elapsed:.1f} s"
        out.append({"kind": kind, "detail": detail, "s": round(elapsed, 4)})
    return json.dumps(out).encode()
