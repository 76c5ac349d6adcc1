"""The scene thread: commands from many threads at once run one at a time, in the order each thread
queued them, none lost; errors come back to the caller. On the real server: concurrent REST steps."""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor

import pytest

from studio.scene.thread import SceneThread, SceneTimeout
from tests.studio.conftest import StudioProcess

WALK = "data/motions/humanoid/humanoid_walk.pkl"


def test_commands_from_many_threads_run_in_order_on_one_thread() -> None:
    owner = SceneThread()
    seen: list[tuple[int, int]] = []
    threads_seen: set[str] = set()

    def record(who: int, i: int) -> int:
        threads_seen.add(threading.current_thread().name)
        seen.append((who, i))
        return len(seen)

    def client(who: int) -> list[int]:
        return [owner.call(record, who, i) for i in range(50)]

    try:
        with ThreadPoolExecutor(8) as pool:
            results = list(pool.map(client, range(8)))
        assert len(seen) == 400 and threads_seen == {"scene"}  # none lost, all on the scene thread
        for who in range(8):
            assert [i for w, i in seen if w == who] == list(range(50))  # each thread's order kept
            assert results[who] == sorted(results[who])  # and each saw its own result, in turn
        assert sorted(r for rs in results for r in rs) == list(range(1, 401))  # one at a time

        with pytest.raises(ZeroDivisionError):  # an error is raised again in the caller
            owner.call(lambda: 1 / 0)
        with pytest.raises(SceneTimeout, match="did not answer within 0.2 s"):
            owner.call(time.sleep, 1.0, timeout=0.2)
        assert owner.call(lambda: "still serving") == "still serving"
    finally:
        owner.close()
    with pytest.raises(RuntimeError, match="stopped"):
        owner.call(lambda: None)


@pytest.mark.integration
def test_concurrent_rest_steps_are_each_applied_once(studio: StudioProcess, test_data) -> None:
    r = studio.post("/api/scene/load_clip", {"path": WALK})
    assert r.status_code == 200, r.text
    start = r.json()
    assert start["frame"] == 0 and not start["playing"]

    def client(_: int) -> list[int]:
        frames = []
        for _ in range(10):
            r = studio.post("/api/scene/step", {"frames": 1})
            assert r.status_code == 200, r.text
            frames.append(r.json()["frame"])
        return frames

    with ThreadPoolExecutor(6) as pool:
        per_client = list(pool.map(client, range(6)))
    every = sorted(f for fs in per_client for f in fs)
    assert every == list(range(1, 61))  # 60 steps, each applied once, each answered with its own result
    assert all(fs == sorted(fs) for fs in per_client)  # a client's steps in the order it sent them
    end = studio.get("/api/scene/state").json()
    assert "frame" in end, end
    assert end["frame"] == 60 and end["updates"] == start["updates"] + 60
