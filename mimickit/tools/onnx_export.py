"""`mimickit export onnx`: a trained policy as one ONNX graph, observations [N, obs_dim] in, the PD
targets the env applies [N, A] out, with the observation normaliser, the action scaling and the env's
action bounds inside the graph (the deterministic action of `agent.compute_action`, clamped as the env's
`_apply_action` clamps it). The model's metadata carries obs_dim, action_dim, the env name and the control
rate. After writing, onnxruntime's actions are checked against torch's on observations recorded by
stepping the env with the policy (`check_onnx`), and the largest difference is printed.

    mimickit export onnx data/models/deepmimic_go2_pace_model.pt --arg_file data/models/deepmimic_go2_pace_model.txt \
        --data_dir ../shared/data --out go2.onnx --mujoco_out go2_sim.npz

`--mujoco_out` also writes what `docs/examples/onnx_mujoco_loop.py` needs to run the policy in a plain
MuJoCo loop (`onnx_sim_file.write_sim_file`). onnx, onnxruntime and onnxscript come with the `onnx` extra.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mimickit.util.errors import MimicKitError
from mimickit.util.paths import DataPaths, check_output_file

if TYPE_CHECKING:
    from mimickit.tools.onnx_graph import CheckResult

CHECK_ENVS = 4  # envs whose observations the check records (torch is imported only when a command runs)


def export_onnx(
    model_file: str | Path, arg_file: str | Path, out: str | Path, data_paths: DataPaths, mujoco_out: str | Path | None
) -> CheckResult:
    """Export, then check on recorded observations; with `mujoco_out` also write the plain-MuJoCo file."""
    from mimickit.runner.policy import load_policy, policy_inputs
    from mimickit.tools.onnx_graph import check_onnx, export_graph, graph_metadata, policy_graph, record_observations

    out = check_output_file(out)
    sim_out = check_output_file(mujoco_out, "--mujoco_out") if mujoco_out else None
    _require_onnx()
    inputs = policy_inputs(arg_file, data_paths)
    if sim_out is not None:  # first: it refuses the envs the example does not reproduce, before the export
        from mimickit.tools.onnx_sim_file import write_sim_file

        write_sim_file(inputs, sim_out)
    env, agent = load_policy(inputs, model_file, num_envs=CHECK_ENVS)
    try:
        graph = policy_graph(env, agent)
        export_graph(graph, env.get_obs_space().shape[0], out, graph_metadata(env, arg_file, model_file))
        return check_onnx(out, graph, record_observations(env, agent), agent)
    finally:
        env.engine.close()


def _require_onnx() -> None:
    try:
        import onnx  # noqa: F401
        import onnxruntime  # noqa: F401
        import onnxscript  # noqa: F401
    except ImportError as e:
        raise MimicKitError(f"ONNX export needs the onnx extra (pip install 'mimickit-studio[onnx]'): {e}") from None


def add_export_parser(sub: Any) -> None:
    """`mimickit export onnx` in the CLI's subparsers."""
    export = sub.add_parser("export", help="export a trained policy for use outside MimicKit")
    esub = export.add_subparsers(dest="export_cmd", required=True)
    p = esub.add_parser("onnx", help="a policy as an ONNX graph (normaliser and action scaling inside), checked")
    p.add_argument("model_file", help="checkpoint (.pt)")
    p.add_argument("--arg_file", required=True, help="arg file naming the env, agent and engine configs of the model")
    p.add_argument("--out", required=True, help="the .onnx file to write")
    p.add_argument("--mujoco_out", help="also write the MuJoCo scene and clip the plain-MuJoCo example reads (.npz)")
    p.add_argument("--data_dir", help="a MimicKit data folder for data/... paths")
    p.set_defaults(func=export_onnx_command)


def export_onnx_command(args: argparse.Namespace) -> int:
    from mimickit.tools.onnx_graph import CHECK_RTOL

    result = export_onnx(args.model_file, args.arg_file, args.out, DataPaths(args.data_dir), args.mujoco_out)
    verdict = "ok" if result.passed else "FAILED"
    print(
        f"wrote {args.out}; onnxruntime vs torch on {result.samples} recorded observations: max |diff| "
        f"{result.max_abs_diff:.3g} (max |action| {result.max_abs_action:.3g}, tolerance {CHECK_RTOL:g} relative): "
        f"{verdict}"
    )
    if args.mujoco_out:
        print(f"wrote {args.mujoco_out} (docs/examples/onnx_mujoco_loop.py reads it)")
    return 0 if result.passed else 1
