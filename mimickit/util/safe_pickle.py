"""A restricted unpickler for untrusted `.pkl` clips: data in, no code run.

Allowed: plain containers and numbers (no globals needed), numpy arrays and scalars, OrderedDict, and
the legacy torch tensor encoding that one official clip uses for its `fps` (a 0-dim float tensor saved
through `torch.storage._load_from_bytes`). The tensor is decoded to a numpy array by reading the legacy
storage format directly; no torch code runs. Every other global (os.system, builtins.eval, ...) is
refused.
"""

from __future__ import annotations

import collections
import io
import pickle
import struct
from typing import Any

import numpy as np

_NUMPY_GLOBALS = {
    ("numpy", "ndarray"),
    ("numpy", "dtype"),
    ("numpy.core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "scalar"),
    ("numpy._core.multiarray", "_reconstruct"),
    ("numpy._core.multiarray", "scalar"),
}
_STORAGE_DTYPES = {
    "FloatStorage": np.float32,
    "DoubleStorage": np.float64,
    "HalfStorage": np.float16,
    "LongStorage": np.int64,
    "IntStorage": np.int32,
    "ShortStorage": np.int16,
    "CharStorage": np.int8,
    "ByteStorage": np.uint8,
    "BoolStorage": np.bool_,
}


class UnsafePickleError(pickle.UnpicklingError):
    """The pickle asked for something other than plain data."""


class _Storage:
    def __init__(self, data: np.ndarray) -> None:
        self.data = data


def _load_torch_storage_bytes(b: bytes) -> _Storage:
    """Decode torch's legacy (non-zip) serialization of one storage, as `_load_from_bytes` would."""
    f = io.BytesIO(b)
    for _ in range(3):  # magic number, protocol version, system info: plain data
        _DataUnpickler(f).load()
    records: dict[str, tuple[type, int]] = {}

    class _StorageRecordUnpickler(_DataUnpickler):
        def find_class(self, module: str, name: str) -> Any:
            if module == "torch" and name in _STORAGE_DTYPES:
                return _STORAGE_DTYPES[name]
            return super().find_class(module, name)

        def persistent_load(self, pid: Any) -> Any:
            if not (isinstance(pid, tuple) and len(pid) >= 5 and pid[0] == "storage"):
                raise UnsafePickleError(f"unsupported persistent id {pid!r}")
            _, dtype, key, _location, numel = pid[:5]
            records[str(key)] = (dtype, int(numel))
            return str(key)

    key = _StorageRecordUnpickler(f).load()
    keys = _DataUnpickler(f).load()
    arrays: dict[str, np.ndarray] = {}
    for k in keys:
        dtype, _ = records[str(k)]
        (numel,) = struct.unpack("<q", f.read(8))
        nbytes = numel * np.dtype(dtype).itemsize
        arrays[str(k)] = np.frombuffer(f.read(nbytes), dtype=dtype, count=numel).copy()
    return _Storage(arrays[str(key)])


def _rebuild_tensor_v2(storage: _Storage, offset: int, size: tuple, stride: tuple, *_: Any) -> np.ndarray:
    itemsize = storage.data.itemsize
    return np.lib.stride_tricks.as_strided(
        storage.data[offset:], shape=tuple(size), strides=tuple(s * itemsize for s in stride)
    ).copy()


class _DataUnpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str) -> Any:
        raise UnsafePickleError(f"refused to load global '{module}.{name}'")


class SafeUnpickler(_DataUnpickler):
    def find_class(self, module: str, name: str) -> Any:
        if (module, name) in _NUMPY_GLOBALS:
            return super(_DataUnpickler, self).find_class(module, name)
        if (module, name) == ("collections", "OrderedDict"):
            return collections.OrderedDict
        if (module, name) == ("torch._utils", "_rebuild_tensor_v2"):
            return _rebuild_tensor_v2
        if (module, name) == ("torch.storage", "_load_from_bytes"):
            return _load_torch_storage_bytes
        raise UnsafePickleError(f"refused to load global '{module}.{name}'")


def safe_loads(data: bytes) -> Any:
    return SafeUnpickler(io.BytesIO(data)).load()
