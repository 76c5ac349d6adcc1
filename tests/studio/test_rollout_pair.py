"""A/B rollouts in-process (no server, no drawing): two checkpoints stepped in lockstep, each episode pair
from the same clip state (the first one too), the one that ends first holding its pose until the other
ends; refused when the two track different clips or are different kinds of env; the player's state and
history rows carry B beside A."""

from __future__ import annotations

import contextlib
import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch

from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_ROOT
from studio.scene.rollout import Frame, Rollout, RolloutPlayer, source_for_checkpoint
from studio.scene.rollout_pair import RolloutPair
from tests.studio.conftest import ENV_YAML, write_checkpoint_dir

pytestmark = pytest.mark.slow

SHIPPED = PROJECT_ROOT / "data" / "models" / "deepmimic_humanoid_demo_model.pt"  # squats the whole 10 s


@pytest.fixture(scope="module")
def fresh_ckpt(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An untrained policy on the same env: it falls within a second or two."""
    return write_checkpoint_dir(tmp_path_factory.mktemp("pair") / "fresh")


@pytest.fixture
def sides(fresh_ckpt: Path):
    a, b = Rollout(source_for_checkpoint(SHIPPED)), Rollout(source_for_checkpoint(fresh_ckpt))
    yield a, b
    a.close()
    b.close()


def start_of(a: Rollout, b: Rollout) -> tuple[float, float, Frame, Frame]:
    return a.env.get_motion_time().item(), b.env.get_motion_time().item(), a.history[-1], b.history[-1]


def test_each_pair_starts_from_one_clip_state_and_the_first_to_end_waits(sides) -> None:
    a, b = sides
    pair = RolloutPair(a, b)
    # The start each side drew when it was built is gone: the history begins at the shared one.
    assert len(a.history) == len(b.history) == 1 and a.episode == b.episode == 0
    starts = [start_of(a, b)]
    while a.episode < 2:
        before = a.episode
        pair.step()
        assert len(a.history) == len(b.history) and a.steps == b.steps  # one frame each per step
        assert a.episode == b.episode  # both start each episode together
        if a.episode != before:
            starts.append(start_of(a, b))
        assert a.steps < 1000, "no third pair within 1000 steps"
    for t_a, t_b, fa, fb in starts:  # one env config: the same clip state is the same qpos
        assert t_a == pytest.approx(t_b) and fa.episode == fb.episode
        np.testing.assert_array_equal(fa.qpos, fb.qpos)
    assert len({round(t, 4) for t, *_ in starts}) == len(starts)  # each pair its own sampled start
    # The trained A runs to the 10 s limit; the untrained B fell long before and held its last pose.
    assert [e.done for e in a.episodes] == [3, 3] and [e.steps for e in a.episodes] == [300, 300]
    assert all(e.done == 1 and e.steps < 300 for e in b.episodes)
    hist = list(b.history)
    held = [i for i, f in enumerate(hist) if f.waiting]
    assert len(held) == sum(300 - e.steps for e in b.episodes)  # B waited out the rest of each of A's episodes
    assert all(hist[i].reward is None and hist[i].terms is None for i in held)
    for i in held:  # its last pose, held
        np.testing.assert_array_equal(hist[i].qpos, hist[i - 1].qpos)
    assert not any(f.waiting for f in a.history)


@pytest.mark.parametrize(
    ("cut", "says"),
    [
        (lambda f: f[: len(f) // 2], r"tracks humanoid_demo_squat\.pkl \(3\.000 s\), B's .* other\.pkl \(1\.467 s\)"),
        (
            lambda f: np.roll(f, len(f) // 3, axis=0),
            r"tracks humanoid_demo_squat\.pkl \(3\.000 s\), B's .* other\.pkl \(3\.000 s\)",
        ),
    ],
    ids=["half-length", "same-length-shifted"],
)
def test_a_pair_of_different_clips_is_refused(fresh_ckpt: Path, tmp_path: Path, cut, says: str) -> None:
    """The demo clip against a half-length copy of it, and against the clip shifted by a third of its
    frames (the same length, other poses at each time): the starts could not be shared."""
    import dataclasses

    from mimickit.anim.motion import load_motion, save_motion

    clip = load_motion(PROJECT_ROOT / "data" / "motions" / "humanoid_demo_squat.pkl")
    other_clip = tmp_path / "other.pkl"
    save_motion(other_clip, dataclasses.replace(clip, frames=cut(clip.frames)))
    other = write_checkpoint_dir(
        tmp_path / "other", ENV_YAML.read_text().replace("data/motions/humanoid_demo_squat.pkl", str(other_clip))
    )
    with built(fresh_ckpt, other) as (a, b), pytest.raises(MimicKitError, match="both must track the same clip") as e:
        RolloutPair(a, b)
    assert re.search(says, str(e.value)) and "\n" not in str(e.value), str(e.value)


def test_a_pair_of_different_env_kinds_is_refused(fresh_ckpt: Path, tmp_path: Path) -> None:
    """A DeepMimic env against an AMP env on the same clip: one line naming both kinds."""
    amp = write_checkpoint_dir(tmp_path / "amp", (PROJECT_ROOT / "data" / "envs" / "amp_humanoid_env.yaml").read_text())
    with built(fresh_ckpt, amp) as (a, b), pytest.raises(MimicKitError) as e:
        RolloutPair(a, b)
    assert "one kind of env: A's env is DeepMimicEnv" in str(e.value) and "B's AMPEnv" in str(e.value), str(e.value)


@contextlib.contextmanager
def built(*checkpoints: Path) -> Iterator[list[Rollout]]:
    """Rollouts of `checkpoints` (their configs beside them), closed afterwards."""
    rollouts = [Rollout(source_for_checkpoint(c)) for c in checkpoints]
    try:
        yield rollouts
    finally:
        for r in rollouts:
            r.close()


def test_the_player_shows_b_beside_a(sides) -> None:
    a, b = sides
    player = RolloutPlayer(a, None, pair=RolloutPair(a, b))
    player.step(90)  # 3 s: the untrained B has ended and waits
    snap = player.snapshot()["rollout"]
    assert snap["b"]["checkpoint"] == str(b.source.checkpoint) and snap["episode"] == 0
    assert snap["b"]["waiting"] and not snap["waiting"]
    assert snap["b"]["episode"] == snap["episode"] and snap["b"]["body_error"]["bodies"] == a.body_names
    rows = player.history_rows()
    assert len(rows) == 90 and all("b" in r for r in rows)
    assert rows[0]["b"]["reward"] is not None and rows[-1]["b"]["reward"] is None  # B's plot stops where it fell
    player.seek(frame=5)  # a history frame: both sides at that frame
    shown = player.snapshot()["rollout"]
    assert shown["episode_step"] == 5 and shown["b"]["episode_step"] == 5 and not shown["b"]["waiting"]
    player.reset()  # New episode: both again from one state
    assert torch.equal(a.env.get_motion_time(), b.env.get_motion_time())
    after = player.snapshot()["rollout"]
    assert after["episode"] == after["b"]["episode"] == 1 and not after["b"]["waiting"]
    with pytest.raises(ValueError, match="A must be the rollout shown"):
        RolloutPlayer(b, None, pair=player.pair)


def test_a_start_outside_the_clips_is_refused_and_a_late_time_clamped(sides) -> None:
    env = sides[0].env
    with pytest.raises(MimicKitError, match=r"motion ids \[3\] outside this env's 1 clips"):
        env.start_next_resets_at(torch.tensor([3]), torch.tensor([0.0]))
    env.start_next_resets_at(torch.tensor([0]), torch.tensor([99.0]))
    env.reset()
    assert env.get_motion_time().item() == pytest.approx(env.motion_lib.get_motion_length(torch.tensor([0])).item())
