"""The restricted unpickler and its opcode pre-scan: what they accept exactly, what they refuse."""

from __future__ import annotations

import pickle
import pickletools
import random
import struct
import tracemalloc
from collections import OrderedDict

import numpy as np
import pytest

from mimickit.util.errors import MimicKitError
from mimickit.util.limits import ClipLimits
from mimickit.util.pickle_scan import MAX_MEMO_INDEX, PickleScanError, scan_pickle
from mimickit.util.safe_pickle import PickleLimitError, UnsafePickleError, safe_loads
from tests.hostile.pkl_cases import f32_storage, glob, v

REAL_DTYPES = ["?", "i1", "u1", "<i2", ">i2", "<u2", "<i4", ">u4", "<i8", "<u8", "<f2", "<f4", ">f4", "<f8", ">f8"]


@pytest.mark.parametrize("protocol", range(6))
@pytest.mark.parametrize("dtype", REAL_DTYPES)
def test_numpy_arrays_round_trip(protocol: int, dtype: str) -> None:
    a = (np.arange(24) % 7).astype(dtype).reshape(2, 3, 4)
    for x in (a, np.asfortranarray(a), a[:, 1:, ::2], a[0, 0, 0:0], np.asarray(a[1, 2, 3])):
        y = safe_loads(pickle.dumps(x, protocol=protocol))
        assert type(y) is np.ndarray and y.dtype == x.dtype and y.shape == x.shape
        np.testing.assert_array_equal(y, x)


def test_containers_keep_sharing_and_order() -> None:
    a = np.arange(3.0)
    obj = {"list": [a, a], "tuple": (a, [a]), "od": OrderedDict(b=2, a=1), "set": {1, 2}, "scalar": np.float32(2.5)}
    y = safe_loads(pickle.dumps(obj, protocol=4))
    assert y["list"][0] is y["list"][1] is y["tuple"][0] is y["tuple"][1][0]
    assert list(y["od"]) == ["b", "a"] and type(y["od"]) is OrderedDict
    assert y["set"] == {1, 2} and y["scalar"] == 2.5 and type(y["scalar"]) is float


@pytest.mark.parametrize(
    "value, needle",
    [
        (np.zeros(2, np.complex64), "'c8'"),
        (np.zeros(2, object), "'O8'"),
        (np.zeros(2, "S3"), "'S3'"),
        (np.zeros(2, "U2"), "'U2'"),
        (np.zeros(2, "V4"), "'V4'"),
        (np.zeros(2, "M8[s]"), "'M8"),
        (np.zeros(2, "m8[s]"), "'m8"),
        (np.zeros(2, [("a", "f4")]), "not allowed"),
        (np.complex128(1), "'c16'"),
        (np.zeros((2, 2), "f4").view([("a", "f4"), ("b", "f4")]), "not allowed"),
    ],
)
def test_non_real_dtypes_refused(value: object, needle: str) -> None:
    with pytest.raises(UnsafePickleError, match=needle):
        safe_loads(pickle.dumps(value))


def test_torch_pickled_tensors_decode_without_torch_code() -> None:
    torch = pytest.importorskip("torch")
    x = {
        "scalar": torch.tensor(30.0),
        "view": torch.arange(6.0).reshape(2, 3)[:, 1:],
        "transposed": torch.arange(12, dtype=torch.int16).reshape(3, 4).T,
        "half": torch.ones(3, dtype=torch.float16),
        "bool": torch.tensor([True, False]),
        "offset": torch.arange(5, dtype=torch.float64)[2:],
        "empty": torch.zeros(0, 4),
    }
    y = safe_loads(pickle.dumps(x))
    for k, t in x.items():
        assert type(y[k]) is np.ndarray, k
        np.testing.assert_array_equal(y[k], t.numpy())
        assert y[k].dtype == t.numpy().dtype, k


def test_file_size_limit_before_parsing() -> None:
    data = pickle.dumps(list(range(1000)))
    with pytest.raises(PickleLimitError, match="over the 0.001 MB limit for a clip .set MIMICKIT_MAX_CLIP_MB"):
        safe_loads(data, ClipLimits(max_file_mb=0.001))
    assert safe_loads(data, ClipLimits(max_file_mb=1)) == list(range(1000))


def test_array_element_limit() -> None:
    data = pickle.dumps(np.zeros(1001, np.uint8))
    with pytest.raises(PickleLimitError, match="an array has 1001 elements, over the limit of 1000"):
        safe_loads(data, ClipLimits(max_values=1000))


def test_repeated_tensor_rebuilds_count_against_the_budget() -> None:
    """One 400 kB storage (memoized) rebuilt into tensors again and again: each copy counts."""
    storage = glob("torch.storage", "_load_from_bytes") + v(f32_storage(np.zeros(100_000))) + b"\x85Rq\x010"
    rebuild = glob("torch._utils", "_rebuild_tensor_v2") + b"(h\x01" + v(0) + v((100_000,)) + v((1,)) + b"\x89)tR"
    few = b"\x80\x03](" + storage + rebuild * 3 + b"e."
    assert [a.shape for a in safe_loads(few, ClipLimits(max_parse_mb=2))] == [(100_000,)] * 3
    with pytest.raises(PickleLimitError, match="a tensor would take the pickle's arrays over 2 MB"):
        safe_loads(b"\x80\x03](" + storage + rebuild * 8 + b"e.", ClipLimits(max_parse_mb=2))


def test_errors_are_unpickling_errors_for_old_callers() -> None:
    """gmr_convert catches pickle.UnpicklingError: every refusal and corruption is one."""
    for data in (b"", b"\x80\x03a.", b"cos\nsystem\n.", b"\x80\x04\x8e" + struct.pack("<Q", 2**62) + b"."):
        with pytest.raises(pickle.UnpicklingError):
            safe_loads(data)


def test_error_text_is_one_line() -> None:
    with pytest.raises(UnsafePickleError) as e:
        safe_loads(b"\x80\x04\x8c\x03a\nb\x8c\x03c\nd\x93.")
    assert "\n" not in str(e.value) and "'a\\nb.c\\nd'" in str(e.value)


# --- the opcode pre-scan -------------------------------------------------------------------------


def test_scan_finds_the_end_of_every_real_clip(test_data) -> None:
    for p in sorted((test_data / "motions").rglob("*.pkl")):
        data = p.read_bytes()
        assert scan_pickle(data)[0] == len(data), p


def test_scan_stops_at_stop_and_walks_protocol_0() -> None:
    data = pickle.dumps({"a": [1.5, 2, "x", b"y", None, True]}, protocol=0)
    assert scan_pickle(data + b"tail")[0] == len(data)


@pytest.mark.parametrize(
    "data, needle",
    [
        (b"\x80\x03]r" + struct.pack("<I", MAX_MEMO_INDEX + 1) + b".", "memo index 1048576"),
        (b"\x80\x03]r" + struct.pack("<I", MAX_MEMO_INDEX) + b".", None),
        (b"(lp1048576\n.", "memo index 1048576"),
        (b"\x80\x04\x8e" + struct.pack("<Q", 5) + b"abcd", "declares 5 bytes but 4 remain"),
        (b"\x80\x04\x8e" + struct.pack("<Q", 4) + b"abcd.", None),
        (b"\x80\x04\x95" + struct.pack("<Q", 3) + b"N.", "declares more bytes"),
        (b"\x80\x03G\x00\x00", "without its STOP"),
        (b"\x80\x03\x82\x01.", "extension codes"),
        (b"\x80\x03\x00.", "invalid pickle opcode 0x00"),
    ],
)
def test_scan_checks_lengths_and_indices(data: bytes, needle: str | None) -> None:
    if needle is None:
        assert scan_pickle(data)[0] == len(data)
    else:
        with pytest.raises(PickleScanError, match=needle):
            scan_pickle(data)


@pytest.mark.parametrize(
    "data",
    [
        pytest.param(b"\x80\x03](" + b"]" * 200_000 + b"e.", id="empty-lists"),
        pytest.param(b"\x80\x03](" + b"N\x85" * 100_000 + b"e.", id="1-tuples"),
        pytest.param(b"\x80\x03](]q\x01" + b"h\x01" * 200_000 + b"e.", id="references"),
        pytest.param(b"\x80\x03" + b"(" * 200_000 + b"N.", id="marks"),
        pytest.param(pickle.dumps([float(i) for i in range(200_000)]), id="floats"),
        pytest.param(b"\x80\x03](" + b"G" + bytes(8) + (b"G" + bytes(8)) * 199_999 + b"e.", id="floats-one-mark"),
        pytest.param(b"\x80\x03](N" + b"2" * 200_000 + b"e.", id="dups"),
        pytest.param(b"\x80\x03](" + b"K\x05" * 200_000 + b"e.", id="small-ints"),
        pytest.param(b"\x80\x04](" + b"\x8f" * 100_000 + b"e.", id="sets"),
    ],
)
def test_scan_estimate_tracks_real_memory(data: bytes) -> None:
    """The pre-scan's estimate against what unpickling (plain pickle, trusted data) really peaks at."""
    _, est = scan_pickle(data)
    tracemalloc.start()
    try:
        obj = pickle.loads(data)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    del obj
    assert 0.75 <= est / peak <= 6, (est, peak)


# --- limits from the environment -----------------------------------------------------------------


def test_limits_from_env() -> None:
    env = {"MIMICKIT_MAX_FRAMES": "5", "MIMICKIT_MAX_CLIP_MB": "0.5", "MIMICKIT_PARSE_TIMEOUT_S": " ", "OTHER": "x"}
    lim = ClipLimits.from_env(env)
    assert (lim.max_frames, lim.max_file_mb, lim.parse_timeout_s) == (5, 0.5, 5.0)
    assert ClipLimits.from_env({}) == ClipLimits()


@pytest.mark.parametrize(
    "var, text, needle",
    [
        ("MIMICKIT_MAX_FRAMES", "lots", "MIMICKIT_MAX_FRAMES='lots' is not a whole number"),
        ("MIMICKIT_MAX_FRAMES", "1.5", "is not a whole number"),
        ("MIMICKIT_MAX_CLIP_MB", "-1", "must be a positive number"),
        ("MIMICKIT_MAX_PARSE_MB", "nan", "must be a positive number"),
        ("MIMICKIT_PARSE_MEMORY_MB", "x" * 500, "is not a number"),
    ],
)
def test_bad_limit_env_is_one_error(var: str, text: str, needle: str) -> None:
    with pytest.raises(MimicKitError, match=needle) as e:
        ClipLimits.from_env({var: text})
    assert len(str(e.value)) < 120


def _genops_end(data: bytes) -> int | None | str:
    """Where the standard library's pure-Python opcode walker finds the STOP (None: it fails;
    "text": an argument is not valid text, which the scan leaves to the unpickler to refuse)."""
    try:
        for op, _, pos in pickletools.genops(data):
            if op.name == "STOP":
                return pos + 1
    except UnicodeDecodeError:
        return "text"
    except Exception:  # noqa: BLE001 - any failure is "not a pickle" for the comparison
        return None
    return None


@pytest.mark.slow
def test_scan_agrees_with_pickletools_on_mutated_clips() -> None:
    """Differential: on clips with corrupted bytes, the scan (fast paths included: float rows,
    row boundaries, numpy-checked blocks of rows) ends where pickletools ends, or refuses."""
    rows = [[float(i * 34 + j) for j in range(34)] for i in range(700)]  # BINPUT rows, then LONG_BINPUT rows
    clips = [pickle.dumps({"loop_mode": 0, "fps": 30, "frames": rows}, protocol=p) for p in (2, 3, 4)]
    rng = random.Random(5)
    agreed = 0
    for _ in range(400):
        b = bytearray(rng.choice(clips))
        for _ in range(rng.randint(1, 3)):
            b[rng.randrange(len(b))] = rng.choice([0x47, 0x65, 0x5D, 0x71, 0x72, 0x28, 0x2E, rng.randrange(256)])
        if rng.random() < 0.2:
            del b[rng.randrange(len(b)) :]
        data = bytes(b)
        want = _genops_end(data)
        if want == "text":
            continue
        try:
            got = scan_pickle(data, 0, ClipLimits(max_parse_mb=1e6))[0]
        except PickleScanError:
            got = None
        if want is None:
            assert got is None, "the scan accepted what pickletools cannot walk"
        else:
            assert got in (want, None), (got, want)
            agreed += got == want
    assert agreed > 100
