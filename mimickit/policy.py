"""A trained policy in its env, built as an arg file says: how `mimickit eval`, `mimickit video`, the
studio's rollouts and the tests load a checkpoint, so that each one plays the same env (the configs and
`--motion_file`) that `mimickit test` would.

    inputs = policy_inputs("data/models/deepmimic_humanoid_walk_model.txt", DataPaths("../shared/data"))
    env, agent = load_policy(inputs, "data/models/deepmimic_humanoid_walk_model.pt", num_envs=4)
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from mimickit.run import RunInputs, resolve_inputs
from mimickit.util.arg_parser import ArgParser
from mimickit.util.paths import PROJECT_DATA, DataPaths

if TYPE_CHECKING:
    from mimickit.envs.sim_env import SimEnv


def policy_inputs(arg_file: str | Path, data_paths: DataPaths = PROJECT_DATA) -> RunInputs:
    """The configs and `--motion_file` an arg file names, each checked to exist (one line otherwise)."""
    args = ArgParser(data_paths)
    args.load_args(["--arg_file", str(arg_file)])
    return resolve_inputs(args, data_paths)


def load_policy(
    inputs: RunInputs, model_file: str | Path, num_envs: int = 1, device: str = "cpu", visualize: bool = False
) -> tuple[SimEnv, Any]:
    """`num_envs` envs of `inputs` (its `motion_file` replacing the env config's clip) and the agent of
    its agent config with `model_file` loaded, in eval mode. A checkpoint that does not fit is one
    MimicKitError line, and the env is closed again."""
    from mimickit.envs.env_builder import build_env  # torch/mujoco-heavy: only when asked
    from mimickit.learning.agent_builder import build_agent

    paths = inputs.data_paths
    env = build_env(inputs.env_file, inputs.engine_file, num_envs, device, visualize, paths, inputs.motion_file)
    try:
        agent = build_agent(inputs.agent_file, env, device, verbose=False, data_paths=paths)
        agent.load(model_file)
    except BaseException:
        env.engine.close()
        raise
    agent.eval()
    return env, agent
