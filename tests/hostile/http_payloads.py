"""Crafted `.pkl` uploads for the HTTP suite and the hostile benchmark: the cases of issue 17 that the
studio must refuse with one line (and survive) or accept, built here rather than stored as files.

Legacy torch tensors are pickled as torch itself pickles them (`torch._utils._rebuild_tensor_v2`
over a storage saved through `torch.storage._load_from_bytes`), with size, stride and offset chosen
to point outside the stored elements.
"""

from __future__ import annotations

import collections
import pickle
import struct
import warnings
from typing import Any

import torch

ROW = [0.0] * 34  # one humanoid frame: root position, root rotation, 28 DoFs


class _Tensor:
    """Pickles as a legacy torch tensor over `values` with the given offset, size and stride."""

    def __init__(self, values: list[float], offset: int, size: tuple[int, ...], stride: tuple[int, ...]) -> None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # TypedStorage is deprecated; its pickle format is the legacy one
            storage = torch.tensor(values, dtype=torch.float32).storage()
        self.args = (storage, offset, size, stride, False, collections.OrderedDict())

    def __reduce__(self) -> tuple[Any, ...]:
        return (torch._utils._rebuild_tensor_v2, self.args)


def clip(fps: Any = 30, frames: Any = None, loop_mode: Any = 0) -> bytes:
    """A clip pickle with the given parts (protocol 4: bytes as BINBYTES, as torch's own clips)."""
    return pickle.dumps({"loop_mode": loop_mode, "fps": fps, "frames": [ROW] * 3 if frames is None else frames}, 4)


def stride_fps(stride: int, size: int = 2) -> bytes:
    """`fps` a view of 1 stored float as size (size,), stride `stride`: reads far outside the storage."""
    return clip(fps=_Tensor([30.0], 0, (size,), (stride,)))


def offset_fps(offset: int) -> bytes:
    return clip(fps=_Tensor([30.0], offset, (), ()))


def heap_view_frames(rows: int = 64) -> bytes:
    """`frames` a [rows, 34] view over 34 stored floats: the other rows would be the server's heap."""
    return clip(frames=_Tensor([1.0] * 34, 0, (rows, 34), (34, 1)))


def huge_count_frames() -> bytes:
    """`frames` a [2**40, 34] zero-stride view: an element count no clip has (terabytes once copied)."""
    return clip(frames=_Tensor([1.0] * 34, 0, (2**40, 34), (0, 1)))


def nested_list_bomb(levels: int, width: int) -> bytes:
    """`frames` nested lists that share every level: a few hundred bytes that expand to
    width**levels numbers when converted to an array."""
    node: Any = [0.0] * width
    for _ in range(levels - 1):
        node = [node] * width
    return clip(frames=node)


def many_frames(n: int = 2_000_000) -> bytes:
    """A valid clip of `n` frames (one shared row: ~4 bytes per frame in the pickle)."""
    return clip(frames=[ROW] * n)


def huge_int_frames() -> bytes:
    return clip(frames=[[10**400] * 34] * 3)


def binbytes8_length() -> bytes:
    """A BINBYTES8 opcode claiming 2**62 bytes follow (a memo/bytes length no file holds)."""
    return b"\x80\x04\x8e" + struct.pack("<Q", 2**62) + b"abc"


def memo_get_unset() -> bytes:
    """A LONG_BINGET of memo index 2**31 - 1, never put."""
    return b"\x80\x04j" + struct.pack("<I", 2**31 - 1) + b"."


def binunicode8_length() -> bytes:
    """A BINUNICODE8 opcode claiming 2**40 bytes of text follow."""
    return b"\x80\x04\x8d" + struct.pack("<Q", 2**40) + b"abc"


class _RunsCode:
    def __reduce__(self) -> tuple[Any, ...]:
        import os

        return (os.system, ("true",))


def code_pickle() -> bytes:
    """A pickle that would run `os.system` on a plain unpickler."""
    return pickle.dumps(_RunsCode(), 4)
