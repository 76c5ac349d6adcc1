"""`warn` / `collect_warnings`: a build's warnings as values, per thread, without touching the filters."""

from __future__ import annotations

import threading
import warnings

import numpy as np
import pytest

from mimickit.anim.motion import LoopMode, Motion, load_motion, save_motion
from mimickit.util.warn import collect_warnings, warn


def test_outside_a_collector_warn_is_a_python_warning() -> None:
    with pytest.warns(UserWarning, match="^ignored key x$"):
        warn("ignored key x")


def test_a_collector_gets_each_message_once_and_python_sees_none() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any warning that escaped the collector would raise here
        with collect_warnings() as caught:
            warn("a")
            warn("b")
            warn("a")
    assert caught == ["a", "b"]


def test_collectors_in_two_threads_at_once_see_only_their_own() -> None:
    both_inside, done = threading.Barrier(2), threading.Barrier(2)
    caught: dict[str, list[str]] = {}

    def build(name: str) -> None:
        with collect_warnings() as mine:
            both_inside.wait(timeout=10)
            warn(f"from {name}")
            done.wait(timeout=10)  # the other thread warns while this collector is still open
        caught[name] = mine

    threads = [threading.Thread(target=build, args=(n,)) for n in ("a", "b")]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=20)
    assert caught == {"a": ["from a"], "b": ["from b"]}


def test_a_clips_nan_columns_are_collected_as_one_line(tmp_path) -> None:
    frames = np.zeros((3, 10), dtype=np.float32)
    frames[1, 7] = np.nan
    save_motion(tmp_path / "nan.pkl", Motion(LoopMode.WRAP, 30, frames))
    with collect_warnings() as caught:
        load_motion(tmp_path / "nan.pkl")
    assert caught == [f"{tmp_path / 'nan.pkl'}: non-finite values in columns [7] replaced by 0"]
