"""The HighTorque PI+ (MimicKit's `hightorque_pi_plus`) with MimicKit's asset and clip from
`$MIMICKIT_TEST_DATA`: the MJCF loads although its colliding meshes are missing, the DeepMimic env builds and
steps, the view-motion env plays the clip as kinematic FK, the arg files build their env and agent, and the
studio's library and scene find PI+ for its clip."""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from collections.abc import Iterator
from pathlib import Path

import pytest
import torch

from mimickit.anim.mjcf_char_model import load_char_model
from mimickit.anim.mjcf_loader import load_mjcf_model
from mimickit.envs.env_builder import build_env, load_env_configs
from mimickit.envs.view_motion_env import ViewMotionEnv
from mimickit.learning.agent_builder import build_agent
from mimickit.util.arg_parser import ArgParser
from mimickit.util.paths import PROJECT_ROOT, DataPaths
from studio.library import Library
from studio.settings import Settings
from tests import conftest
from tests.studio.conftest import StudioProcess

# PI+'s meshes are not in MimicKit's data; the loader drops them with a warning (checked below).
pytestmark = [pytest.mark.slow, pytest.mark.filterwarnings(r"ignore:.*mesh file\(s\) missing:UserWarning")]

ENGINE = PROJECT_ROOT / "data/engines/mujoco_engine.yaml"
ASSET = "assets/hightorque_pi_plus/pi_22dof.xml"
CLIP = "motions/hightorque_pi_plus/pi_plus_walk.pkl"
DOFS = 22
BODIES = 24  # base_link, the fixed head, 2 legs of 6 and 2 arms of 5 links


@pytest.fixture(scope="module")
def pi_data(test_data: Path) -> Iterator[Path]:
    """MimicKit's data with PI+ in it (the tests that take it are skipped without)."""
    if not (test_data / ASSET).is_file() or not (test_data / CLIP).is_file():
        pytest.skip(f"no PI+ asset and clip under {test_data}")
    yield test_data


DATA = DataPaths(conftest.test_data_dir())
"""`data/...` paths of the env yamls resolve in MimicKit's data folder, as with `--data_dir`."""


SYNTHETIC = """<mujoco><asset><mesh name="m" file="gone.stl"/></asset><worldbody>
  <body name="torso"><freejoint/><inertial pos="0 0 0" mass="2" diaginertia=".1 .1 .1"/><geom type="mesh" mesh="m"/>
    <body name="cap" pos="0 0 .2"><geom type="mesh" mesh="m"/></body>
    <body name="leg" pos="0 0 -.2"><joint axis="0 1 0"/><inertial pos="0 0 0" mass="1" diaginertia=".01 .01 .01"/>
      <geom type="mesh" mesh="m"/><geom type="box" size=".05 .05 .05"/></body></body></worldbody></mujoco>"""


def test_missing_colliding_meshes_are_dropped_keeping_inertial_masses(tmp_path: Path) -> None:
    """No reference data needed: a colliding mesh geom whose file is gone is dropped, not an error."""
    xml = tmp_path / "robot.xml"
    xml.write_text(SYNTHETIC)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        model = load_mjcf_model(xml)
    (text,) = [str(x.message) for x in w]
    assert "dropped 3 (3 colliding) geoms" in text
    assert "no collision geometry left: torso, cap;" in text and "mass came from dropped geoms: cap" in text
    assert model.ngeom == 1 and model.nv == 7
    assert model.body_mass[1:].tolist() == pytest.approx([2.0, 0.0, 1.0])


def test_mjcf_loads_without_its_meshes_and_says_what_is_lost(pi_data: Path) -> None:
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        char = load_char_model(pi_data / ASSET)
    assert (char.get_num_joints(), char.get_dof_size()) == (BODIES, DOFS)
    text = " ".join(str(x.message) for x in w)
    assert "colliding" in text and "no collision geometry left: base_link" in text
    assert "mass came from dropped geoms: head" in text
    # The feet keep their boxes: they are not among the bodies left without collision geometry.
    assert "l_ankle_roll_link" not in text.split("no collision geometry left:")[1].split(";")[0]


def test_deepmimic_env_builds_resets_to_the_clip_and_steps(pi_data: Path) -> None:
    env = build_env(PROJECT_ROOT / "data/envs/deepmimic_pi_plus_env.yaml", ENGINE, 4, data_paths=DATA)
    obs, _ = env.reset()
    assert env.get_action_space().shape == (DOFS,)
    assert obs.shape[0] == 4 and torch.isfinite(obs).all()
    info = env.score_state()  # the reward terms a step computes, for the reset state itself
    for name, value in info["reward_terms"].items():
        torch.testing.assert_close(value, torch.ones(4), atol=2e-3, rtol=0, msg=name)
    for _ in range(10):
        obs, reward, _, _ = env.step(torch.zeros(4, DOFS))
    assert torch.isfinite(obs).all() and ((reward > 0) & (reward <= 1)).all()
    # The feet's boxes keep the robot on the floor (no body sinks through it).
    assert env.engine.get_body_pos(env.get_char_id())[:, :, 2].min() > 0.0


def test_view_motion_plays_the_clip_as_kinematic_fk(pi_data: Path) -> None:
    env_cfg, engine_cfg = load_env_configs(PROJECT_ROOT / "data/envs/view_motion_pi_plus_env.yaml", ENGINE)
    env = ViewMotionEnv(env_cfg, engine_cfg, 2, data_paths=DATA)
    env.reset()
    lib, kin = env.motion_lib, env.char_model
    ids = torch.zeros(2, dtype=torch.long)
    worst = 0.0
    for _ in range(60):  # 2 s of the clip
        env.step(torch.zeros(2, kin.get_dof_size()))
        f = lib.calc_motion_frame(ids, env.get_env_time())
        body_pos, _ = kin.forward_kinematics(f.root_pos, f.root_rot, f.joint_rot)
        sim = env.engine.get_body_pos(env.get_char_id())
        worst = max(worst, (sim - body_pos).norm(dim=-1).max().item())
    assert worst < 1e-3, f"engine bodies {worst * 1000:.2f} mm off the clip's FK"


@pytest.mark.parametrize(
    "arg_file",
    ["deepmimic_pi_plus_ppo_args.txt", "view_motion_pi_plus_args.txt", "add_pi_plus_args.txt", "amp_pi_plus_args.txt"],
)
def test_arg_files_build_their_env(arg_file: str, pi_data: Path) -> None:
    args = ArgParser()
    args.load_args(["--arg_file", str(PROJECT_ROOT / "args" / arg_file)])
    env = build_env(
        PROJECT_ROOT / args.parse_string("env_config"),
        PROJECT_ROOT / args.parse_string("engine_config"),
        2,
        data_paths=DATA,
    )
    obs, _ = env.reset()
    if not args.has_key("agent_config"):
        return
    agent = build_agent(PROJECT_ROOT / args.parse_string("agent_config"), env, verbose=False)
    assert agent.get_obs_size() == env.get_obs_space().shape[0]
    action = agent.compute_action(obs)
    assert action.shape == (2, DOFS) and torch.isfinite(action).all()


@pytest.mark.integration
@pytest.mark.parametrize("method", ["add", "amp"])
def test_adversarial_arg_files_train_two_iterations(method: str, pi_data: Path, tmp_path: Path) -> None:
    """MimicKit's add_pi_plus_args.txt and amp_pi_plus_args.txt counterparts: two iterations of 32 envs, with
    their discriminator's loss logged. (With 2 or 8 envs, 64 or 256 samples an iteration, AMP's critic
    sometimes blew up in its second iteration, the G1's as well: predictions of -1e19, a diverged run; the
    observation normaliser's first estimate comes from that one iteration's samples, as the reference's.)"""
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "mimickit.cli", "train", "--arg_file", f"args/{method}_pi_plus_args.txt"]
    cmd += ["--data_dir", str(pi_data), "--num_envs", "32", "--max_samples", "2048", "--out_dir", str(out)]
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=PROJECT_ROOT, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    rows = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert [row["samples"] for row in rows] == [1024, 2048] and all(row["disc_loss"] > 0 for row in rows)


@pytest.mark.integration
def test_the_command_line_says_what_was_dropped_once_on_one_line(pi_data: Path, tmp_path: Path) -> None:
    """The MJCF loader and the engine both load the character, and both warn of its missing meshes."""
    cmd = [sys.executable, "-m", "mimickit.cli", "test", "--arg_file", "args/deepmimic_pi_plus_walk_ppo_args.txt"]
    cmd += ["--data_dir", str(pi_data), "--num_envs", "1", "--test_episodes", "1", "--out_dir", str(tmp_path)]
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=PROJECT_ROOT)
    assert r.returncode == 0, r.stderr
    lines = [line for line in r.stderr.splitlines() if "mesh file(s) missing" in line or "Warning" in line]
    assert len(lines) == 1 and lines[0].startswith(f"warning: {pi_data / ASSET}: 32 mesh file(s) missing"), r.stderr


def test_studio_library_guesses_pi_plus_for_its_clip(pi_data: Path, tmp_path: Path) -> None:
    library = Library(Settings(data_dir=pi_data, runs_dir=tmp_path, start_viser=False).resolved())
    chars = {c["path"]: c for c in library.characters()}
    pi = chars[f"data/{ASSET}"]
    assert "error" not in pi and pi["frame_dim"] == 6 + DOFS
    clips = {m["path"]: m for m in library.motions()}
    assert clips[f"data/{CLIP}"]["character"] == f"data/{ASSET}"


@pytest.mark.integration
def test_studio_scene_plays_the_clip_on_pi_plus(pi_data: Path, tmp_path: Path) -> None:
    """The real server guesses the character (today's failure was "no character fits this clip")."""
    studio = StudioProcess(tmp_path, pi_data)
    try:
        r = studio.post("/api/scene/load_clip", {"path": f"data/{CLIP}"})
    finally:
        studio.stop()
    assert r.status_code == 200, r.text
    s = r.json()
    assert s["char"].endswith(ASSET) and s["num_frames"] == 240 and s["fps"] == 50
    assert 0.3 < s["root_pos"][2] < 0.45  # PI+'s base_link stands 0.39 m up
