"""`mimickit export onnx`: onnxruntime's actions against torch's on recorded observations, the graph's
metadata and dynamic batch, and the plain-MuJoCo example (docs/examples/onnx_mujoco_loop.py): its
observation equals the env's for the same state, its rollout tracks the clip as the env's does."""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

import mujoco  # noqa: F401  (its first import probes glfw in a subprocess: here, at collection, not in a test)
import numpy as np
import pytest
import torch

from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA_DIR, PROJECT_ROOT, DataPaths
from tests.conftest import test_data_dir as reference_data_dir

ort = pytest.importorskip("onnxruntime")
pytest.importorskip("onnxscript")

from mimickit.cli import run_cli  # noqa: E402
from mimickit.runner.policy import load_policy, policy_inputs  # noqa: E402
from mimickit.tools.onnx_export import add_export_parser, export_onnx  # noqa: E402
from mimickit.tools.onnx_graph import check_onnx, policy_graph  # noqa: E402

pytestmark = pytest.mark.slow  # each export builds envs and rolls the policy out (seconds)

MODELS = PROJECT_DATA_DIR / "models"
EXAMPLE = PROJECT_ROOT / "docs" / "examples" / "onnx_mujoco_loop.py"
NEEDS_DATA = pytest.mark.skipif(reference_data_dir() is None, reason="MIMICKIT_TEST_DATA is not set")
POLICIES = [
    pytest.param("deepmimic_humanoid_demo_model", id="demo"),
    pytest.param("deepmimic_go2_pace_model", id="go2", marks=NEEDS_DATA),
    pytest.param("deepmimic_g1_walk_model", id="g1", marks=NEEDS_DATA),
]


@dataclass(frozen=True)
class Exported:
    name: str
    onnx: Path
    sim: Path
    data_paths: DataPaths

    @property
    def model(self) -> Path:
        return MODELS / f"{self.name}.pt"

    @property
    def args(self) -> Path:
        return MODELS / f"{self.name}.txt"


@pytest.fixture(scope="module", params=POLICIES)
def exported(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Exported:
    name, folder = request.param, tmp_path_factory.mktemp("onnx")
    data_dir = reference_data_dir() if name != "deepmimic_humanoid_demo_model" else None
    ex = Exported(name, folder / "policy.onnx", folder / "sim.npz", DataPaths(data_dir))
    result = export_onnx(ex.model, ex.args, ex.onnx, ex.data_paths, ex.sim)
    print(f"{name}: onnxruntime vs torch max |diff| {result.max_abs_diff:.3g} over {result.samples} observations")
    assert result.passed and result.samples > 100
    return ex


@pytest.fixture(scope="module")
def example() -> ModuleType:
    spec = importlib.util.spec_from_file_location("onnx_mujoco_loop", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_graph_metadata_and_dynamic_batch(exported: Exported) -> None:
    session = ort.InferenceSession(str(exported.onnx), providers=["CPUExecutionProvider"])
    meta = session.get_modelmeta().custom_metadata_map
    obs_dim, action_dim = int(meta["obs_dim"]), int(meta["action_dim"])
    assert meta["env_name"] == "deepmimic" and float(meta["control_freq"]) == 30.0
    assert meta["model_file"] == exported.model.name
    for batch in (1, 7):
        (action,) = session.run(["action"], {"obs": np.zeros((batch, obs_dim), dtype=np.float32)})
        assert action.shape == (batch, action_dim) and np.isfinite(action).all()


def test_check_sees_a_graph_that_differs_from_torch(exported: Exported) -> None:
    """The check can fail: after the export, move the torch policy's observation mean."""
    env, agent = load_policy(policy_inputs(exported.args, exported.data_paths), exported.model, num_envs=2)
    try:
        obs = env.reset()[0].clone()
        graph = policy_graph(env, agent)
        assert check_onnx(exported.onnx, graph, obs, agent).passed
        agent._obs_norm.set_mean_std(agent._obs_norm.get_mean() + 0.5, agent._obs_norm.get_std())
        failed = check_onnx(exported.onnx, graph, obs, agent)
    finally:
        env.engine.close()
    assert not failed.passed and failed.max_abs_diff > 1e-3


def test_example_observation_equals_the_envs(exported: Exported, example: ModuleType) -> None:
    """Step the env with its policy; at every step put its MuJoCo state into the example's MjData: the
    example's observation equals the env's (float32 rounding)."""
    m, d, sim = example.load_sim(str(exported.sim))
    env, agent = load_policy(policy_inputs(exported.args, exported.data_paths), exported.model, num_envs=1)
    try:
        start = 7
        env.start_next_resets_at(torch.zeros(1, dtype=torch.long), torch.tensor([start * float(sim["dt"])]))
        obs, _ = env.reset()
        for k in range(30):
            state, _ = env.engine.physics_state()
            d.qpos[:], d.qvel[:] = state[0, 1 : 1 + m.nq], state[0, 1 + m.nq : 1 + m.nq + m.nv]
            example.update_kinematics(m, d)
            mine = example.observation(example.character_state(m, d, sim), sim, start + k)
            np.testing.assert_allclose(mine, obs[0].numpy(), rtol=1e-5, atol=1e-5, err_msg=f"step {k}")
            obs = env.step(agent.compute_action(obs))[0]
    finally:
        env.engine.close()


def env_episode_errors(ex: Exported, start: int, steps: int, dt: float) -> list[float]:
    """The env's per-step `body_pos_err` (what `mimickit test` averages into pos_err_m) for one episode
    from clip step `start`, driven by the torch policy."""
    env, agent = load_policy(policy_inputs(ex.args, ex.data_paths), ex.model, num_envs=1)
    try:
        env.start_next_resets_at(torch.zeros(1, dtype=torch.long), torch.tensor([start * dt]))
        obs, _ = env.reset()
        errors = []
        for _ in range(steps):
            obs, _, done, info = env.step(agent.compute_action(obs))
            errors.append(float(info["tracking"]["body_pos_err"][0]))
            if bool(done.any()):
                break
    finally:
        env.engine.close()
    return errors


def test_example_tracks_the_clip_as_the_env_does(exported: Exported, example: ModuleType) -> None:
    m, d, sim = example.load_sim(str(exported.sim))
    policy = ort.InferenceSession(str(exported.onnx), providers=["CPUExecutionProvider"])
    start = int(sim["clip_steps"]) // 3
    mine = example.run_episode(policy, m, d, sim, start)
    env = env_episode_errors(exported, start, len(mine), float(sim["dt"]))
    print(f"{exported.name}: mean pos_err_m, example {np.mean(mine):.4f}, env {np.mean(env):.4f} ({len(mine)} steps)")
    assert len(env) == len(mine)  # the env's episode was not cut short by a fall either
    assert abs(np.mean(mine) - np.mean(env)) <= 0.1 * np.mean(env)


@pytest.mark.integration
def test_example_script_runs_without_mimickit(exported: Exported) -> None:
    code = (
        "import runpy, sys; sys.argv = sys.argv[1:]\n"
        "try:\n    runpy.run_path(sys.argv[0], run_name='__main__')\nexcept SystemExit as e:\n    assert not e.code\n"
        "assert not [m for m in sys.modules if m.split('.')[0] in ('mimickit', 'torch')], 'imported mimickit'\n"
    )
    cmd = [sys.executable, "-c", code, str(EXAMPLE), str(exported.onnx), str(exported.sim), "--episodes", "1"]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "mean pos_err_m" in out.stdout


def cli(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="mimickit")
    add_export_parser(parser.add_subparsers(dest="cmd", required=True))
    return run_cli(parser, argv)


def test_latent_policies_are_refused_in_one_line() -> None:
    from mimickit.learning.ase_agent import ASEAgent

    with pytest.raises(MimicKitError, match="ASEAgent: its policy also takes a latent"):
        policy_graph(None, ASEAgent.__new__(ASEAgent))  # refused before it reads anything of the agent


def test_cli_exports_and_prints_the_check(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    model, args = MODELS / "deepmimic_humanoid_demo_model.pt", MODELS / "deepmimic_humanoid_demo_model.txt"
    out = tmp_path / "new_folder" / "demo.onnx"
    assert cli(["export", "onnx", str(model), "--arg_file", str(args), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert out.is_file() and "max |diff|" in printed and printed.rstrip().endswith("ok")


def test_cli_refuses_bad_input_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = MODELS / "deepmimic_humanoid_demo_model.txt"
    assert cli(
        ["export", "onnx", str(tmp_path / "none.pt"), "--arg_file", str(args), "--out", str(tmp_path / "a.onnx")]
    )
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and "none.pt" in err and "\n" not in err


@NEEDS_DATA
def test_mujoco_out_refuses_an_env_the_example_does_not_reproduce(tmp_path: Path) -> None:
    model, args = MODELS / "amp_humanoid_walk_model.pt", MODELS / "amp_humanoid_walk_model.txt"
    with pytest.raises(MimicKitError, match="not the DeepMimic env"):
        export_onnx(model, args, tmp_path / "amp.onnx", DataPaths(reference_data_dir()), tmp_path / "amp.npz")
    assert not (tmp_path / "amp.onnx").exists()
