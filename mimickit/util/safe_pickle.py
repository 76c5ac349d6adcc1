"""A restricted unpickler for untrusted `.pkl` clips: data in, no code run, no memory read.

Allowed: plain containers and numbers (no globals needed), numpy arrays and scalars of real dtypes
(bool, int, uint, float), OrderedDict, and the legacy torch tensor encoding that one official clip
uses for its `fps` (a 0-dim float tensor saved through `torch.storage._load_from_bytes`). The tensor
is decoded by reading the legacy storage format directly; no torch code runs. Every other global
(os.system, builtins.eval, ...) is refused.

Every number that says where data lies (tensor sizes, strides and offsets; array shapes; storage
element counts; byte lengths; memo indices) is checked against the bytes actually stored before
anything is allocated or read, so a crafted file gets one `UnsafePickleError`, never a view of
other memory, a crash or a giant allocation. `pickle_scan.scan_pickle` checks the opcode stream
first; arrays built on the way count against the same memory budget.
"""

from __future__ import annotations

import gc
import io
import math
import pickle
import re
from collections import OrderedDict
from typing import Any

import numpy as np

from mimickit.util.limits import ClipLimits, env_var_for
from mimickit.util.pickle_scan import PickleScanError, PickleScanLimitError, scan_pickle

_TORCH_MAGIC = 0x1950A86A20F9469CFC6C
_TORCH_PROTOCOL = 1001
_MAX_NDIM = 8
# Storage class name -> element dtype, for the legacy torch format (little-endian, as it is saved).
_STORAGE_DTYPES = {
    "FloatStorage": np.dtype("<f4"),
    "DoubleStorage": np.dtype("<f8"),
    "HalfStorage": np.dtype("<f2"),
    "LongStorage": np.dtype("<i8"),
    "IntStorage": np.dtype("<i4"),
    "ShortStorage": np.dtype("<i2"),
    "CharStorage": np.dtype("i1"),
    "ByteStorage": np.dtype("u1"),
    "BoolStorage": np.dtype("?"),
}
_REAL_DTYPE = re.compile(r"[biuf][1248]")
_BYTE_ORDERS = ("<", ">", "|", "=")


class UnsafePickleError(pickle.UnpicklingError):
    """The pickle asked for something other than plain data, or is malformed."""


class PickleLimitError(UnsafePickleError):
    """The pickle is well-formed but over a size limit (the message names the variable to raise it)."""


def safe_loads(data: bytes, limits: ClipLimits | None = None) -> Any:
    """Unpickle untrusted `data` allowing plain data only; one UnsafePickleError for anything else.

    MemoryError is let through (the caller knows its memory bound; see `mimickit.util.guarded`).
    """
    limits = limits or ClipLimits.from_env()
    data = bytes(data)
    if len(data) > limits.max_file_bytes:
        raise PickleLimitError(
            f"{len(data)} bytes is over the {limits.max_file_mb:g} MB limit for a clip"
            f" (set {env_var_for('max_file_mb')} to allow more)"
        )
    if not data:
        raise UnsafePickleError("the file is empty")
    end = _scan(data, 0, limits)
    if end != len(data):
        raise UnsafePickleError(f"{len(data) - end} unexpected bytes after the pickle's end (byte {end})")
    unpickler = SafeUnpickler(data, limits)
    obj = _load(unpickler, "pickle")
    return _swap_pending(obj, {}, 0) if unpickler.pending else obj


def _scan(data: bytes, start: int, limits: ClipLimits) -> int:
    try:
        end, _ = scan_pickle(data, start, limits)
    except PickleScanLimitError as e:
        raise PickleLimitError(str(e)) from None
    except PickleScanError as e:
        raise UnsafePickleError(str(e)) from None
    except Exception as e:  # a scanner bug must still be one line about the file (tests call it directly)
        raise UnsafePickleError(f"corrupt pickle: {_short_error(e)}") from None
    return end


def _load(unpickler: pickle.Unpickler, what: str) -> Any:
    # Cyclic GC off while loading: it rescans every tracked object as millions of new lists
    # arrive, which made a list bomb 6x slower (3M lists: 4.4 s against 0.8 s); there are no
    # cycles to find in freshly built data. Process-wide, so other threads skip GC for the moment.
    gc_was_on = gc.isenabled()
    gc.disable()
    try:
        return unpickler.load()
    except (UnsafePickleError, MemoryError):
        raise
    except RecursionError:
        raise UnsafePickleError(f"{what} is nested too deeply") from None
    except Exception as e:  # hostile bytes reach every error path of the C unpickler
        raise UnsafePickleError(f"corrupt {what}: {_short_error(e)}") from None
    finally:
        if gc_was_on:
            gc.enable()


def _swap_pending(obj: Any, done: dict[int, Any], depth: int) -> Any:
    """`obj` with each _PendingArray replaced by its array: lists and dicts in place, tuples rebuilt.

    Each container is visited once (`done`), so shared references cost nothing extra."""
    if isinstance(obj, _PendingArray):
        if obj.array is None:
            raise UnsafePickleError("a numpy array in the pickle has no state")
        return obj.array
    kind = type(obj)
    if kind not in (list, tuple, dict, OrderedDict, set, frozenset):
        return obj
    if id(obj) in done:
        return done[id(obj)]
    if depth > 32:
        raise UnsafePickleError("the pickle's containers are nested more than 32 deep around an array")
    done[id(obj)] = obj
    if kind is list:
        for i, x in enumerate(obj):
            obj[i] = _swap_pending(x, done, depth + 1)
    elif kind in (dict, OrderedDict):
        for k, v in obj.items():
            if isinstance(k, _PendingArray):
                raise UnsafePickleError("a numpy array cannot be a dict key")
            obj[k] = _swap_pending(v, done, depth + 1)
    elif kind is tuple:
        done[id(obj)] = obj = tuple(_swap_pending(x, done, depth + 1) for x in obj)
    elif any(isinstance(x, _PendingArray) for x in obj):
        raise UnsafePickleError("a numpy array cannot be in a set")
    return obj


def _short_error(e: BaseException) -> str:
    text = _printable(str(e)[:200])
    return f"{type(e).__name__}: {text}" if text else type(e).__name__


def _printable(text: str) -> str:
    """Untrusted text for a one-line message: newlines and other control characters escaped."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def _refused(module: str, name: str) -> UnsafePickleError:
    return UnsafePickleError(f"refused to load global '{_printable(module[:80])}.{_printable(name[:80])}'")


class _Budget:
    """Bytes of arrays the unpickler builds, against the limit the opcode scan also uses."""

    def __init__(self, limits: ClipLimits) -> None:
        self.limits = limits
        self.used = 0

    def take(self, nbytes: int, what: str) -> None:
        self.used += nbytes
        if self.used > self.limits.max_parse_bytes:
            raise PickleLimitError(
                f"{what} would take the pickle's arrays over {self.limits.max_parse_mb:g} MB"
                f" (set {env_var_for('max_parse_mb')} to allow more)"
            )

    def check_count(self, count: int, what: str) -> None:
        if count > self.limits.max_values:
            raise PickleLimitError(
                f"{what} has {_short(count)} elements, over the limit of {self.limits.max_values}"
                f" (set {env_var_for('max_values')} to allow more)"
            )


class _Marker:
    """Stands in for a class the pickle names but may not call (numpy.ndarray, a torch storage type)."""

    __slots__ = ("name", "dtype")

    def __init__(self, name: str, dtype: np.dtype | None = None) -> None:
        self.name = name
        self.dtype = dtype

    def __setstate__(self, state: Any) -> None:
        raise UnsafePickleError(f"{self.name} takes no state")


_NDARRAY = _Marker("numpy.ndarray")


class _DtypeSpec:
    """`numpy.dtype(...)` as pickled: a real dtype once checked, never a numpy call on raw input."""

    __slots__ = ("dtype",)

    def __init__(self, spec: Any = None, align: Any = False, copy: Any = True) -> None:
        if not (isinstance(spec, str) and _REAL_DTYPE.fullmatch(spec)) or not isinstance(align, bool):
            raise UnsafePickleError(f"dtype {_short(spec)} is not allowed (only bool, int, uint and float)")
        self.dtype = np.dtype(spec)

    def __setstate__(self, state: Any) -> None:
        # numpy writes (3, byteorder, None, None, None, -1, -1, 0); any other form carries fields,
        # subarrays or flags that a plain number type does not have.
        if not (
            isinstance(state, tuple)
            and len(state) == 8
            and state[0] in (3, 4)
            and state[1] in _BYTE_ORDERS
            and state[2:5] == (None, None, None)
            and state[5:] == (-1, -1, 0)
        ):
            raise UnsafePickleError("a dtype's state is not that of a plain number type")
        if state[1] in "<>" and self.dtype.itemsize > 1:
            self.dtype = self.dtype.newbyteorder(state[1])


def _real_dtype(spec: Any) -> np.dtype:
    dtype = getattr(spec, "dtype", None) if isinstance(spec, (_DtypeSpec, _Marker)) else None
    if not isinstance(dtype, np.dtype) or dtype.kind not in "biuf":
        raise UnsafePickleError(f"array dtype {_short(spec)} is not allowed (only bool, int, uint and float)")
    return dtype


def _check_shape(shape: Any, what: str) -> tuple[int, ...]:
    if not isinstance(shape, tuple) or len(shape) > _MAX_NDIM:
        raise UnsafePickleError(f"{what} shape must be a tuple of at most {_MAX_NDIM} sizes, got {_short(shape)}")
    for s in shape:
        if not _is_int(s) or s < 0:
            raise UnsafePickleError(f"{what} shape {_short(shape)} holds {_short(s)}, not a size >= 0")
    return shape


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _short(v: Any) -> str:
    """A bounded description of an untrusted value (never the repr of a container or a giant int)."""
    if _is_int(v):
        return repr(v) if abs(v) < 10**30 else f"an integer of {v.bit_length()} bits"
    if isinstance(v, (float, bool)) or v is None:
        return repr(v)
    if isinstance(v, str):
        return repr(v[:40] + ("..." if len(v) > 40 else ""))
    if isinstance(v, tuple) and len(v) <= _MAX_NDIM and all(_is_int(x) or x is None for x in v):
        return "(" + ", ".join(_short(x) for x in v) + ("," if len(v) == 1 else "") + ")"
    return f"a {type(v).__name__}"


class _PendingArray:
    """What numpy's `_reconstruct` returns here: BUILD hands it the array's state, which is checked
    (shape, real dtype, exactly the bytes that shape needs) before numpy builds the array from it.
    `safe_loads` swaps each one for its array once the pickle is loaded."""

    __slots__ = ("array", "budget")

    def __init__(self, budget: _Budget) -> None:
        self.array: np.ndarray | None = None
        self.budget = budget

    def __setstate__(self, state: Any) -> None:
        if not isinstance(state, tuple) or len(state) not in (4, 5):
            raise UnsafePickleError("an array's state is not (version, shape, dtype, fortran, bytes)")
        if len(state) == 5 and state[0] != 1:
            raise UnsafePickleError(f"array state version {_short(state[0])} is not 1")
        shape, spec, fortran, raw = state[-4:]
        shape = _check_shape(shape, "array")
        dtype = _real_dtype(spec)
        if not isinstance(fortran, bool) or not isinstance(raw, (bytes, bytearray)):
            raise UnsafePickleError("an array's state must hold a bool order flag and its bytes")
        self.array = _array_from_bytes(raw, dtype, shape, "F" if fortran else "C", self.budget)


def _array_from_bytes(raw: bytes | bytearray, dtype: np.dtype, shape: tuple[int, ...], order: str, budget: _Budget):
    count = math.prod(shape)
    budget.check_count(count, "an array")
    if count * dtype.itemsize != len(raw):
        raise UnsafePickleError(
            f"an array of shape {_short(shape)} and dtype {dtype} needs {count * dtype.itemsize} bytes,"
            f" the file holds {len(raw)}"
        )
    budget.take(len(raw), "an array")
    return np.frombuffer(raw, dtype).reshape(shape, order=order).copy(order="K")


class SafeUnpickler(pickle.Unpickler):
    """The clip unpickler: the globals above only, arrays through checked constructors."""

    def __init__(self, data: bytes, limits: ClipLimits) -> None:
        super().__init__(io.BytesIO(data))
        self._limits = limits
        self._budget = _Budget(limits)
        self.pending = 0  # arrays built through _reconstruct, to swap in after loading
        self._globals = {
            ("numpy", "ndarray"): _NDARRAY,
            ("numpy", "dtype"): _DtypeSpec,
            ("collections", "OrderedDict"): OrderedDict,
            ("torch._utils", "_rebuild_tensor_v2"): self._rebuild_tensor_v2,
            ("torch.storage", "_load_from_bytes"): self._load_from_bytes,
            ("_codecs", "encode"): _latin1_bytes,
            ("__builtin__", "bytes"): _empty_bytes,  # how protocols 0-2 write b""
            ("builtins", "bytes"): _empty_bytes,
        }
        for core in ("numpy.core", "numpy._core"):
            self._globals[(f"{core}.multiarray", "_reconstruct")] = self._reconstruct
            self._globals[(f"{core}.multiarray", "scalar")] = self._scalar
            self._globals[(f"{core}.numeric", "_frombuffer")] = self._frombuffer

    def find_class(self, module: str, name: str) -> Any:
        found = self._globals.get((module, name))
        if found is None and name == "complex" and module in ("builtins", "__builtin__"):
            raise UnsafePickleError("complex numbers are not allowed (a clip holds real numbers only)")
        if found is None:
            raise _refused(module, name)
        return found

    def persistent_load(self, pid: Any) -> Any:
        raise UnsafePickleError("persistent ids are not allowed in a clip")

    def _reconstruct(self, subtype: Any, shape: Any, dtype: Any) -> _PendingArray:
        # numpy pickles an array as _reconstruct(ndarray, (0,), b'b') followed by its state.
        if subtype is not _NDARRAY or shape != (0,) or dtype != b"b":
            raise UnsafePickleError("numpy _reconstruct called with other than (ndarray, (0,), b'b')")
        self.pending += 1
        return _PendingArray(self._budget)

    def _scalar(self, spec: Any, raw: Any = None) -> bool | int | float:
        dtype = _real_dtype(spec)
        if not isinstance(raw, bytes) or len(raw) != dtype.itemsize:
            raise UnsafePickleError(f"a numpy {dtype} scalar needs {dtype.itemsize} bytes")
        return np.frombuffer(raw, dtype)[0].item()  # a python number: nothing for BUILD to poke

    def _frombuffer(self, buf: Any, spec: Any, shape: Any, order: Any) -> np.ndarray:
        shape = _check_shape(shape, "array")
        dtype = _real_dtype(spec)
        if not isinstance(buf, (bytes, bytearray)) or order not in ("C", "F"):
            raise UnsafePickleError("numpy _frombuffer needs bytes and order 'C' or 'F'")
        return _array_from_bytes(buf, dtype, shape, order, self._budget)

    def _load_from_bytes(self, raw: Any) -> _Storage:
        if not isinstance(raw, bytes):
            raise UnsafePickleError("torch _load_from_bytes needs bytes")
        storage = _read_legacy_storage(raw, self._limits)
        self._budget.take(storage.data.nbytes, "a tensor storage")
        return storage

    def _rebuild_tensor_v2(self, storage: Any, offset: Any, size: Any, stride: Any, *rest: Any) -> np.ndarray:
        if not isinstance(storage, _Storage):
            raise UnsafePickleError("a tensor must be rebuilt from a storage")
        index = _tensor_index(storage.data.size, offset, size, stride, self._budget)
        self._budget.take(index.size * storage.data.itemsize, "a tensor")
        return np.asarray(storage.data[index])  # a 0-d tensor stays an array, never a numpy scalar


def _tensor_index(numel: int, offset: Any, size: Any, stride: Any, budget: _Budget) -> np.ndarray:
    """The flat storage index of every element of a (size, stride, offset) view, all bounds-checked."""
    if not (isinstance(size, tuple) and isinstance(stride, tuple) and len(size) == len(stride)):
        raise UnsafePickleError(f"tensor size {_short(size)} and stride {_short(stride)} must be tuples of one length")
    _check_shape(size, "tensor")
    if len(stride) > _MAX_NDIM or not all(_is_int(s) and s >= 0 for s in stride):
        raise UnsafePickleError(f"tensor stride {_short(stride)} must hold whole numbers >= 0")
    if not _is_int(offset) or not 0 <= offset <= numel:
        raise UnsafePickleError(f"tensor offset {_short(offset)} must be a whole number in 0..{numel}")
    count = math.prod(size)
    budget.check_count(count, "a tensor")
    if count:
        last = offset + sum((n - 1) * s for n, s in zip(size, stride, strict=True))
        if last >= numel:
            raise UnsafePickleError(
                f"a tensor of size {_short(size)}, stride {_short(stride)} and offset {_short(offset)}"
                f" reaches element {_short(last)} of a storage of {numel}"
            )
    index = np.full(size, offset, dtype=np.int64)
    for axis, (n, s) in enumerate(zip(size, stride, strict=True)):
        shape = [1] * len(size)
        shape[axis] = n
        index += (np.arange(n, dtype=np.int64) * s).reshape(shape)
    return index


def _latin1_bytes(text: Any, encoding: Any = None) -> bytes:
    """`_codecs.encode(text, 'latin1')`: how protocols 0-2 write a bytes object (e.g. an array's data)."""
    if not isinstance(text, str) or encoding not in ("latin1", "latin-1"):
        raise UnsafePickleError("_codecs.encode is allowed only as (str, 'latin1'), how bytes are pickled")
    return text.encode("latin1")


def _empty_bytes(*args: Any) -> bytes:
    if args:
        raise UnsafePickleError("bytes(...) is allowed only with no arguments, how b'' is pickled")
    return b""


class _Storage:
    """One storage of torch's legacy format, as a flat numpy array."""

    __slots__ = ("data",)

    def __init__(self, data: np.ndarray) -> None:
        self.data = data

    def __setstate__(self, state: Any) -> None:
        raise UnsafePickleError("a storage takes no state")


class _RecordUnpickler(pickle.Unpickler):
    """The small pickles inside torch's legacy format: plain data, storage types, storage records."""

    def __init__(self, data: bytes, records: dict[str, tuple[np.dtype, int]] | None = None) -> None:
        super().__init__(io.BytesIO(data))
        self._records = records

    def find_class(self, module: str, name: str) -> Any:
        if self._records is not None and module == "torch" and name in _STORAGE_DTYPES:
            return _Marker(f"torch.{name}", _STORAGE_DTYPES[name])
        raise _refused(module, name)

    def persistent_load(self, pid: Any) -> Any:
        ok = self._records is not None and isinstance(pid, tuple) and len(pid) in (5, 6) and pid[0] == "storage"
        if not ok or not isinstance(pid[1], _Marker) or not isinstance(pid[2], str) or not _is_int(pid[4]):
            raise UnsafePickleError("a tensor storage record is not ('storage', type, key, location, size)")
        if len(pid) == 6 and pid[5] is not None:
            raise UnsafePickleError("tensor storage views are not supported")
        self._records[pid[2]] = (pid[1].dtype, pid[4])
        return pid[2]


def _read_legacy_storage(raw: bytes, limits: ClipLimits) -> _Storage:
    """Decode torch's legacy (non-zip) serialization of one storage, as `_load_from_bytes` would."""
    pos = 0
    header = []
    for _ in range(3):  # magic number, protocol version, system info
        end = _scan(raw, pos, limits)
        header.append(_load(_RecordUnpickler(raw[pos:end]), "tensor header"))
        pos = end
    magic, protocol, info = header
    if magic != _TORCH_MAGIC or protocol != _TORCH_PROTOCOL:
        raise UnsafePickleError("not torch's legacy tensor format (wrong magic number or protocol)")
    if not isinstance(info, dict) or info.get("little_endian") is not True:
        raise UnsafePickleError("only little-endian legacy tensors are supported")
    records: dict[str, tuple[np.dtype, int]] = {}
    end = _scan(raw, pos, limits)
    key = _load(_RecordUnpickler(raw[pos:end], records), "tensor record")
    pos = end
    end = _scan(raw, pos, limits)
    keys = _load(_RecordUnpickler(raw[pos:end]), "tensor keys")
    pos = end
    if not isinstance(keys, list) or not all(isinstance(k, str) and k in records for k in keys) or key not in keys:
        raise UnsafePickleError("a tensor's storage keys do not match its records")
    arrays: dict[str, np.ndarray] = {}
    for k in keys:
        dtype, _ = records[k]
        if pos + 8 > len(raw):
            raise UnsafePickleError("a tensor's storage is cut off (truncated file)")
        numel = int.from_bytes(raw[pos : pos + 8], "little", signed=True)
        pos += 8
        if numel < 0 or numel * dtype.itemsize > len(raw) - pos:
            raise UnsafePickleError(
                f"a tensor storage declares {numel} elements; the file holds {len(raw) - pos} bytes"
            )
        arrays[k] = np.frombuffer(raw, dtype, count=numel, offset=pos)
        pos += numel * dtype.itemsize
    if pos != len(raw):
        raise UnsafePickleError(f"{len(raw) - pos} unexpected bytes after a tensor's storage")
    return _Storage(arrays[key])
