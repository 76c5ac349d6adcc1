"""What an env declares to a viewer (mimickit/envs/viewable.py) is what it does: a clip-tracking env's
per-body errors, reward weights and clips match its steps; a plain character env declares only the
character. The studio's rollout asks `isinstance` for these instead of probing attributes."""

from __future__ import annotations

import pytest
import torch

from mimickit.envs.env_builder import ENVS, build_env
from mimickit.envs.viewable import TracksReference, Viewable
from mimickit.util.paths import PROJECT_DATA_DIR

ENGINE = PROJECT_DATA_DIR / "engines" / "mujoco_engine.yaml"
DEEPMIMIC = PROJECT_DATA_DIR / "envs" / "deepmimic_humanoid_env.yaml"
TRACKING = {
    "deepmimic",
    "static_objects",
    "amp",
    "add",
    "ase",
    "smp",
    "task_location",
    "task_steering",
    "task_dodgeball",
}
# Rewarded for the reference's pose at each step; AMP's are for its style.
POSE_TRACKING = {"deepmimic", "static_objects", "add"}


@pytest.mark.parametrize("name", ENVS.names)
def test_every_character_env_is_viewable_and_the_clip_trackers_say_so(name: str) -> None:
    cls = ENVS.resolve(name)
    assert issubclass(cls, Viewable) and not cls.__abstractmethods__
    assert issubclass(cls, TracksReference) == (name in TRACKING), name
    if name in TRACKING:  # a class-level answer: the property reads no state
        assert cls.tracks_pose.fget(None) == (name in POSE_TRACKING), name


def test_a_tracking_env_offers_what_it_declares() -> None:
    env = build_env(DEEPMIMIC, ENGINE, num_envs=1, visualize=True)
    try:
        assert isinstance(env, TracksReference)
        assert env.get_ref_char_id() is not None  # the ghost, with visualize
        assert env.ref_char_offset == (2.0, 0.0, 0.0)  # the env yaml's ref_char_offset: where the ghost stands
        env.reset()
        _, _, _, info = env.step(torch.zeros(1, env.get_action_space().shape[0]))
        assert set(info["reward_terms"]) == set(env.reward_weights)
        errors = env.body_pos_errors()
        assert errors.shape == (1, len(env.char_model.get_body_names())) and bool((errors >= 0).all())
        assert len(env.motion_lib.motion_files) == env.motion_lib.num_motions() >= 1
        ids, times = env.get_motion_ids(), env.get_motion_time()
        env.start_next_resets_at(ids, times)  # the next reset starts at this clip state
        env.reset()
        assert torch.equal(env.get_motion_ids(), ids)
        torch.testing.assert_close(env.get_motion_time(), times)
    finally:
        env.engine.close()
