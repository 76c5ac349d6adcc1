"""A run trained on the Newton engine (optional extra, `make test-newton`) is rolled out in the studio,
exported as a replay through the studio's scene, rendered by `mimickit video` and benched: every viewer
draws through `Engine.mujoco_view`, none reaches into an engine.

Warp's CPU kernels are single-threaded: 4 envs, one training iteration, 1 s episodes."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("newton", reason="the Newton engine needs the optional extra: pip install .[newton]")

from mimickit.tools.bench import run_bench  # noqa: E402
from mimickit.tools.video import VideoOptions, policy_video  # noqa: E402
from mimickit.util.paths import PROJECT_DATA_DIR, PROJECT_ROOT  # noqa: E402
from studio.scene.replay import rollout_frames, write_rollout_replay  # noqa: E402
from studio.scene.rollout import Rollout, RolloutPlayer, source_for_checkpoint  # noqa: E402
from tests.tools.test_video import character_pixels, decode  # noqa: E402

pytestmark = pytest.mark.integration

NEWTON_YAML = PROJECT_DATA_DIR / "engines" / "newton_engine.yaml"
DEEPMIMIC = PROJECT_DATA_DIR / "envs" / "deepmimic_humanoid_env.yaml"
AGENT = PROJECT_DATA_DIR / "agents" / "deepmimic_humanoid_ppo_cpu_agent.yaml"
NUM_ENVS, STEPS_PER_ITER = 4, 32
REF_CHAR_OFFSET = np.array([2.0, 0.0, 0.0])  # deepmimic_humanoid_env.yaml
W, H = 160, 120


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """`mimickit train` on Newton for one iteration (4 envs × 32 steps)."""
    tmp = tmp_path_factory.mktemp("newton_run")
    env_yaml, agent_yaml = tmp / "env.yaml", tmp / "agent.yaml"
    env_yaml.write_text(DEEPMIMIC.read_text().replace("episode_length: 10.0", "episode_length: 1.0"))
    agent_yaml.write_text(AGENT.read_text().replace("test_episodes: 32", "test_episodes: 1"))
    out = tmp / "run"
    cmd = [sys.executable, "-m", "mimickit.cli", "train", "--engine_config", str(NEWTON_YAML), "--env_config",
           str(env_yaml), "--agent_config", str(agent_yaml), "--num_envs", str(NUM_ENVS), "--test_episodes", "1",
           "--max_samples", str(NUM_ENVS * STEPS_PER_ITER), "--out_dir", str(out), "--rand_seed", "1"]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=PROJECT_ROOT)
    assert done.returncode == 0, done.stderr[-3000:]
    rows = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert [r["samples"] for r in rows] == [NUM_ENVS * STEPS_PER_ITER]  # one iteration
    assert "engine_name: newton" in (out / "engine_config.yaml").read_text()
    return out


@pytest.fixture(scope="module")
def rollout(run_dir: Path):
    r = Rollout(source_for_checkpoint(run_dir / "model.pt"), history_s=2.0)
    yield r
    r.close()


def test_studio_rolls_out_a_newton_checkpoint(rollout: Rollout) -> None:
    r = rollout
    engine = r.env.engine
    assert engine.get_name() == "newton" and r.control_freq == pytest.approx(30.0)
    assert len(r.ghost_bodies) == 15 and r.root_body not in r.ghost_bodies
    for _ in range(40):  # past the 1 s episode: one reset
        r.step()
    assert r.episode >= 1 and r.episodes[0].steps <= 30
    # The last recorded frame is the engine's state (a step that ends an episode records its last pose and
    # then the reset's start pose): the character's root where Newton has it, the ghost ref_char_offset
    # from the reference the env tracks.
    frame = r.history[-1]
    xpos, xmat = r.pose(frame)
    np.testing.assert_allclose(xpos[r.root_body], engine.get_root_pos(r.env.get_char_id())[0].numpy(), atol=2e-5)
    ref = r.env.get_ref_state()["root_pos"][0].numpy()
    np.testing.assert_allclose(xpos[r.ghost_bodies[0]], ref + REF_CHAR_OFFSET, atol=2e-5)
    assert np.isfinite(xmat).all()
    old = r.history[3]  # scrubbing back draws a recorded step from its qpos
    np.testing.assert_allclose(r.pose(old)[0][r.root_body], old.qpos[:3], atol=1e-6)
    # The player steps it and draws it (no scene: the drawing path is the replay test's).
    player = RolloutPlayer(r, None)
    try:
        steps = r.steps
        player.step(2)
        assert r.steps == steps + 2 and player.snapshot()["rollout"]["live"]
    finally:
        player.close()


def test_newton_rollout_replays_through_the_studio_scene(rollout: Rollout, tmp_path: Path) -> None:
    """The studio's scene (viser, the rollout model with its translucent ghost) draws the recorded steps."""
    info = write_rollout_replay(rollout_frames(rollout), tmp_path / "replay.viser")
    assert info.kind == "rollout" and info.frames == len(rollout.history) and info.bytes > 1000


def test_mimickit_video_renders_a_newton_policy(run_dir: Path, tmp_path: Path) -> None:
    arg_file = tmp_path / "args.txt"
    arg_file.write_text(
        "".join(f"--{k} {run_dir / f'{k}.yaml'}\n" for k in ("env_config", "agent_config", "engine_config"))
    )
    out = tmp_path / "policy.mp4"
    info = policy_video(run_dir / "model.pt", arg_file, out, VideoOptions(0.5, W, H))
    _, frames = decode(out)
    assert info.frames == len(frames) == 15
    assert character_pixels(frames[-1]) > 100
    ghost = frames[-1][..., 1].astype(int) > frames[-1][..., 2].astype(int) + 15  # the green reference
    assert ghost.sum() > 50


def test_bench_on_newton_reports_env_figures_only(run_dir: Path) -> None:
    result = run_bench(str(NEWTON_YAML), str(run_dir / "env_config.yaml"), 2, steps=2, warmup=1, rounds=1)
    assert result["engine"] == "newton" and result["env_steps_per_s"] > 0
    assert result["raw_sim_steps_per_s"] is None and result["ratio"] is None and result["raw_mode"] is None
