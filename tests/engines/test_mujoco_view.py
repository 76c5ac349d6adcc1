"""`Engine.mujoco_view`, what viewers draw from, on both engines: each object's body ids (by obj_id) are
that object's bodies, posed as the engine's getters say, in every env, with pending setter edits applied;
`bench_util.raw_rollout`, the bench's baseline, exists for the MuJoCo engine only.

The Newton cases run where the optional extra is installed (`make test-newton`)."""

from __future__ import annotations

import importlib.util
import warnings

import mujoco
import numpy as np
import pytest
import torch

from mimickit.engines.bench_util import raw_rollout
from mimickit.envs.char_env import CharEnv
from mimickit.envs.env_builder import build_env
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA_DIR

DEEPMIMIC = PROJECT_DATA_DIR / "envs" / "deepmimic_humanoid_env.yaml"
NUM_ENVS = 2
NO_NEWTON = importlib.util.find_spec("newton") is None
# Newton is an integration case: warp starts a process (`uname -p`) when it first builds a model.
NEWTON = pytest.param(
    "newton", marks=[pytest.mark.skipif(NO_NEWTON, reason="no Newton extra"), pytest.mark.integration]
)
ENGINES = ["mujoco", NEWTON]


def engine_yaml(name: str):
    return PROJECT_DATA_DIR / "engines" / f"{name}_engine.yaml"


@pytest.fixture(scope="module", params=ENGINES)
def env(request: pytest.FixtureRequest):
    """The DeepMimic env with its reference character (visualize), two envs, a few steps in."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Newton's CPU-only warnings
        env = build_env(DEEPMIMIC, engine_yaml(request.param), NUM_ENVS, "cpu", visualize=True)
    env.reset()
    gen = torch.Generator().manual_seed(0)
    for _ in range(3):
        env.step(torch.randn(NUM_ENVS, env.get_action_space().shape[0], generator=gen) * 0.3)
    yield env
    env.engine.close()


def body_name(model: mujoco.MjModel, b: int) -> str:
    return mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, int(b)) or ""


def assert_posed_as_engine(env: CharEnv, i: int) -> None:
    """Env i's view: every object's bodies where the engine's getters put them (rotation up to sign)."""
    engine = env.engine
    view = engine.mujoco_view(i)
    for o, obj in enumerate(view.objects):
        np.testing.assert_allclose(view.data.xpos[obj.body_ids], engine.get_body_pos(o)[i].numpy(), atol=2e-5)
        xyzw = view.data.xquat[obj.body_ids][:, [1, 2, 3, 0]]
        rot = engine.get_body_rot(o)[i].numpy()
        err = np.minimum(np.abs(xyzw - rot).max(axis=-1), np.abs(xyzw + rot).max(axis=-1))
        assert err.max() < 2e-5, f"env {i} object {o}: body rotations {err.max():.2e} apart"


def test_view_objects_are_the_env_objects(env: CharEnv) -> None:
    engine, view = env.engine, env.engine.mujoco_view(0)
    char, ghost = env.get_char_id(), env.get_ref_char_id()
    assert (char, ghost) == (0, 1)
    assert [(o.name, o.is_visual) for o in view.objects] == [("character", False), ("reference", True)]
    for o, obj in enumerate(view.objects):
        kin_names = engine.get_obj_body_names(o)
        assert len(obj.body_ids) == engine.get_obj_num_bodies(o) == len(kin_names) == 15
        # The ids are this object's bodies, in the kinematic DFS order (root first).
        assert [body_name(view.model, b).rsplit("/", 1)[-1] for b in obj.body_ids] == kin_names
        assert np.isin(view.model.geom_bodyid, obj.body_ids).any(), f"object {o} has nothing to draw"
        assert not obj.body_ids.flags.writeable
    assert not set(view.objects[char].body_ids) & set(view.objects[ghost].body_ids)
    assert engine.mujoco_view(1).model is view.model  # one model; each env its own data
    assert engine.mujoco_view(1).data is not view.data


def test_view_poses_every_env_as_the_engine(env: CharEnv) -> None:
    for i in range(NUM_ENVS):
        assert_posed_as_engine(env, i)
    # The ghost stands ref_char_offset (2 m along x) from the reference the env tracks.
    view, ghost = env.engine.mujoco_view(1), env.get_ref_char_id()
    ref_root = env.get_ref_state()["root_pos"][1].numpy()
    np.testing.assert_allclose(view.data.xpos[view.objects[ghost].body_ids[0]], ref_root + [2.0, 0.0, 0.0], atol=2e-5)


def test_view_applies_pending_setter_edits(env: CharEnv) -> None:
    engine, char = env.engine, env.get_char_id()
    before = engine.mujoco_view(0).data.xpos[engine.mujoco_view(0).objects[char].body_ids[0]].copy()
    moved = engine.get_root_pos(char)[1].clone() + torch.tensor([0.5, -0.25, 0.1])
    engine.set_root_pos(torch.tensor([1]), char, moved[None])
    view = engine.mujoco_view(1)  # no getter in between: the view pushes the edit itself
    np.testing.assert_allclose(view.data.xpos[view.objects[char].body_ids[0]], moved.numpy(), atol=2e-5)
    root_qpos = view.data.qpos[:3]  # the character's free joint comes first in the model
    np.testing.assert_allclose(root_qpos, moved.numpy(), atol=2e-5)
    after = engine.mujoco_view(0)
    np.testing.assert_allclose(after.data.xpos[after.objects[char].body_ids[0]], before, atol=1e-7)  # env 0 stays
    assert_posed_as_engine(env, 1)


def test_view_of_an_env_that_does_not_exist(env: CharEnv) -> None:
    with pytest.raises(MimicKitError, match=r"mujoco_view: env 2 is out of range \(the engine has 2 envs\)"):
        env.engine.mujoco_view(NUM_ENVS)


def test_raw_rollout_is_the_mujoco_engines_own(env: CharEnv) -> None:
    raw = raw_rollout(env.engine)
    if env.engine.get_name() == "newton":
        assert raw is None  # the bench reports env figures only
        return
    try:
        assert raw.model is env.engine.mujoco_view(0).model and raw.substeps == env.engine.config.substeps
        assert raw.state.shape[0] == NUM_ENVS
    finally:
        raw.close()


def test_env_without_a_ghost_has_no_reference_id() -> None:
    env = build_env(DEEPMIMIC, engine_yaml("mujoco"), 1, "cpu", visualize=False)
    try:
        assert env.get_ref_char_id() is None
        assert [o.name for o in env.engine.mujoco_view(0).objects] == ["character"]
    finally:
        env.engine.close()
