"""A trained policy in its env, built as an arg file says: how `mimickit eval`, `mimickit video`, the
studio's rollouts and the tests load a checkpoint, so that each one plays the same env (the configs and
`--motion_file`) that `mimickit test` would; and what `mimickit test` reports of its test episodes
(`test_result`; `mimickit eval` counts its episodes its own way, `mimickit.tools.evaluate`).

    inputs = policy_inputs("data/models/deepmimic_humanoid_walk_model.txt", DataPaths("../shared/data"))
    env, agent = load_policy(inputs, "data/models/deepmimic_humanoid_walk_model.pt", num_envs=4)
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from mimickit.runner.inputs import RunInputs, resolve_inputs
from mimickit.util.arg_parser import ArgParser
from mimickit.util.errors import MimicKitError
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
    its agent config with `model_file` loaded, in eval mode. A checkpoint that does not fit, or whose
    normaliser cannot normalise (a std of 0), is one MimicKitError line, and the env is closed again."""
    from mimickit.envs.env_builder import build_env  # torch/mujoco-heavy: only when asked
    from mimickit.learning.agent_builder import build_agent

    paths = inputs.data_paths
    env = build_env(inputs.env_file, inputs.engine_file, num_envs, device, visualize, paths, inputs.motion_file)
    try:
        agent = build_agent(inputs.agent_file, env, device, verbose=False, data_paths=paths)
        agent.load(model_file)
        check_normalizers(agent, model_file)
    except BaseException:
        env.engine.close()
        raise
    agent.eval()
    return env, agent


def check_normalizers(agent: Any, model_file: str | Path) -> None:
    """MimicKitError when a normaliser of `agent` has a std that is not positive: (x - mean) / 0 makes
    the observations, and so the actions, NaN or infinite. A trainer never writes one (its variance has a
    floor); a hand-edited or foreign checkpoint can."""
    from mimickit.learning.normalizer import Normalizer

    for name, module in agent.named_modules():
        if not isinstance(module, Normalizer):
            continue
        std = module.get_std()
        bad = std <= 0  # NaN is refused by `agent.load` already
        if bool(bad.any()):
            first = int(bad.flatten().nonzero()[0])
            raise MimicKitError(
                f"{model_file}: normaliser {name} has std {float(std.flatten()[first]):g} at entry {first} "
                f"({int(bad.sum())} of {std.numel()} not positive): it would divide by zero; not rolling it out"
            )


def test_result(agent: Any, env: Any, episodes: int) -> dict[str, Any]:
    """`mimickit test`'s result: the agent's test episodes (`test_model`), the env's tracking errors
    (`test_tracking`) and how the episodes ended (`episode_ends`: fail / succ / time counts summed over
    processes; empty for envs without a reference motion)."""
    from mimickit.learning import mp_util

    result: dict[str, Any] = agent.test_model(episodes).to_dict()
    result["tracking"] = test_tracking(getattr(env, "tracking_summary", dict)())
    ends = getattr(env, "episode_end_summary", dict)()
    result["episode_ends"] = {k: int(mp_util.reduce_sum(v)) for k, v in ends.items()}
    return result


def test_tracking(summary: dict[str, float]) -> dict[str, float]:
    """The env's tracking errors over the test steps, averaged over processes, plus `pos_err_m`: the
    reference code's position error (body_pos_err, the mean over bodies of the root-relative body
    position error, metres; no global root term). The paper's Table 1 errors are the env's
    `paper_pos_err_m` and `paper_dof_vel_err` (deepmimic_rewards.paper_errors). Empty for envs without
    a reference motion."""
    from mimickit.learning import mp_util

    tracking = {k: float(mp_util.reduce_mean(v)) for k, v in sorted(summary.items())}
    if "body_pos_err" in tracking:
        tracking["pos_err_m"] = tracking["body_pos_err"]
    return tracking


# ---------------------------------------------------------------- training
