"""The stream's sampling and followers (`studio.live_state`), in-process: one watcher however many
streams listen and none once they have left; a change wakes the listeners; a failing read keeps the
last value; the followers of a run's console.log and metrics.jsonl send each line or row once."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest

from studio.live_state import (
    LOG_TAIL_BYTES,
    METRICS_BATCH_ROWS,
    LiveState,
    LogFollower,
    MetricsFollower,
    Sampled,
    Versioned,
)


class Source:
    """A scene whose state the test sets; counts the reads."""

    def __init__(self) -> None:
        self.value = {"frame": 0}
        self.reads = 0
        self.fail = False

    def __call__(self) -> dict:
        self.reads += 1
        if self.fail:
            raise RuntimeError("scene gone")
        return dict(self.value)


def watchers() -> int:
    return sum(1 for t in asyncio.all_tasks() if t.get_coro().__name__ == "_watch" and not t.done())


def test_one_watcher_for_all_listeners_and_none_without() -> None:
    scene = Source()
    live = LiveState({"scene": Sampled(scene), "runs": Sampled(list, every=10)})

    async def listen(stop: asyncio.Event) -> None:
        async with live.subscribe():
            await stop.wait()

    async def main() -> None:
        stop = asyncio.Event()
        tasks = [asyncio.create_task(listen(stop)) for _ in range(3)]
        await asyncio.sleep(0.3)
        assert live.watching and watchers() == 1
        assert live.topics["scene"].value == {"frame": 0} and live.topics["runs"].value == []
        stop.set()
        await asyncio.gather(*tasks)
        await asyncio.sleep(0)
        assert not live.watching and watchers() == 0
        reads = scene.reads
        await asyncio.sleep(0.3)
        assert scene.reads == reads  # nobody listens: nothing is read

    asyncio.run(main())


def test_a_change_wakes_the_listeners_and_a_failed_read_keeps_the_last_value() -> None:
    scene = Source()
    live = LiveState({"scene": Sampled(scene), "runs": Sampled(list, every=10)})

    async def main() -> None:
        async with live.subscribe():
            seen = live.versions
            scene.value = {"frame": 5}
            await asyncio.wait_for(live.wait(seen, timeout=60), 10)
            scene_topic = live.topics["scene"]
            assert scene_topic.value == {"frame": 5} and scene_topic.version == seen[0] + 1
            scene.fail = True
            reads = scene.reads
            while scene.reads < reads + 3:
                await asyncio.sleep(0.05)
            assert scene_topic.value == {"frame": 5} and live.watching

    asyncio.run(main())


def test_versioned_counts_content_changes_only() -> None:
    v = Versioned()
    assert v.update([{"id": 1, "status": "running"}]) and v.version == 1
    assert not v.update([{"status": "running", "id": 1}]) and v.version == 1  # same content, other order
    assert v.update([{"id": 1, "status": "finished"}]) and v.version == 2


def test_log_follower_sends_each_line_once(tmp_path: Path) -> None:
    path = tmp_path / "console.log"
    follower = LogFollower(path)
    assert follower.read() == {"reset": True, "lines": []}  # no file yet
    path.write_text("$ train\none\ntwo\n")
    assert follower.read() == {"reset": False, "lines": ["$ train", "one", "two"]}  # appended to the empty log
    assert follower.read() is None
    with path.open("a") as f:
        f.write("thr")
    assert follower.read() is None  # half a line waits for its end
    with path.open("a") as f:
        f.write("ee\nfour\n")
    assert follower.read() == {"reset": False, "lines": ["three", "four"]}
    path.write_text("$ again\n")  # shorter than what was read: starts again
    assert follower.read() == {"reset": True, "lines": ["$ again"]}


def test_log_follower_starts_at_the_tail_of_a_long_log(tmp_path: Path) -> None:
    path = tmp_path / "console.log"
    path.write_text("".join(f"line {i:06d}\n" for i in range(2 * LOG_TAIL_BYTES // 12)))
    got = LogFollower(path).read()
    assert got["reset"] and len(got["lines"]) == 200
    assert got["lines"][-1] == path.read_text().splitlines()[-1]
    assert all(line.startswith("line ") and len(line) == 11 for line in got["lines"])  # no half line


def test_metrics_follower_batches_the_backlog(tmp_path: Path) -> None:
    path = tmp_path / "metrics.jsonl"
    n = 2 * METRICS_BATCH_ROWS + 7
    path.write_text(
        "".join(json.dumps({"iteration": i, "loss": float("nan") if i == 3 else 1.0}) + "\n" for i in range(n))
    )
    follower = MetricsFollower(path)
    batches = follower.read()
    assert [(b["reset"], b["start"], len(b["rows"])) for b in batches] == [
        (True, 0, METRICS_BATCH_ROWS),
        (False, METRICS_BATCH_ROWS, METRICS_BATCH_ROWS),
        (False, 2 * METRICS_BATCH_ROWS, 7),
    ]
    assert batches[0]["rows"][3] == {"iteration": 3, "loss": None, "nonfinite": {"loss": "nan"}}
    assert follower.read() == []
    with path.open("a") as f:
        f.write(json.dumps({"iteration": n}) + "\n")
    assert follower.read() == [{"reset": False, "start": n, "rows": [{"iteration": n}]}]
    assert MetricsFollower(tmp_path / "none.jsonl").read() == [{"reset": True, "start": 0, "rows": []}]


def test_a_topic_without_a_period_is_read_at_start_and_when_woken() -> None:
    jobs = Source()
    live = LiveState({"scene": Sampled(Source()), "jobs": Sampled(jobs, every=None)})

    async def main() -> None:
        async with live.subscribe():
            seen, reads = live.versions, jobs.reads
            assert reads == 1 and live.topics["jobs"].value == {"frame": 0}
            jobs.value = {"frame": 9}
            await asyncio.sleep(0.5)
            assert jobs.reads == reads and live.versions == seen  # not woken: not read
            live.wake("jobs")
            await asyncio.wait_for(live.wait(seen, timeout=60), 10)
            assert jobs.reads == reads + 1 and live.topics["jobs"].value == {"frame": 9}

    asyncio.run(main())
    with pytest.raises(KeyError, match="no topic 'job'"):
        live.wake("job")
