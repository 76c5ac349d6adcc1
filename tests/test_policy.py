"""`load_policy`: a checkpoint in the env its arg file names, `--motion_file` included, as `mimickit test`
builds it; a checkpoint that does not fit is one line."""

from __future__ import annotations

from pathlib import Path

import mujoco  # noqa: F401  (imported at collection: its GLFW probe starts a process, allowed only then)
import pytest

from mimickit.runner.policy import load_policy, policy_inputs
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA_DIR
from tests.conftest import DEMO_CLIP, write_shifted_demo_clip
from tests.studio.conftest import smaller_obs_env_yaml

DEMO_MODEL = PROJECT_DATA_DIR / "models" / "deepmimic_humanoid_demo_model.pt"
DEMO_ARGS = PROJECT_DATA_DIR / "models" / "deepmimic_humanoid_demo_model.txt"


def test_the_arg_files_clip_and_configs_make_the_policys_env(tmp_path: Path) -> None:
    env, agent = load_policy(policy_inputs(DEMO_ARGS), DEMO_MODEL, num_envs=2)
    assert [Path(f) for f in env.motion_lib.motion_files] == [DEMO_CLIP] and env.num_envs == 2
    assert not agent.training  # eval mode
    env.engine.close()
    shifted = write_shifted_demo_clip(tmp_path / "shifted.pkl")
    arg_file = tmp_path / "args.txt"
    arg_file.write_text(DEMO_ARGS.read_text() + f"--motion_file {shifted}\n")
    env, _ = load_policy(policy_inputs(arg_file), DEMO_MODEL)
    assert [Path(f) for f in env.motion_lib.motion_files] == [shifted]
    env.engine.close()


def test_a_checkpoint_of_another_agent_is_one_line(tmp_path: Path) -> None:
    """A checkpoint whose observation size is not the env's: one line, and the env is closed again."""
    arg_file = tmp_path / "args.txt"
    env_yaml = tmp_path / "env.yaml"
    env_yaml.write_text(smaller_obs_env_yaml())
    arg_file.write_text(DEMO_ARGS.read_text().replace("data/envs/deepmimic_humanoid_env.yaml", str(env_yaml)))
    with pytest.raises(MimicKitError, match="deepmimic_humanoid_demo_model.pt"):
        load_policy(policy_inputs(arg_file), DEMO_MODEL)
