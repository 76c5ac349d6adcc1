"""The ONNX graph of a policy and its check (`mimickit export onnx`, see `onnx_export`): `PolicyGraph`
wraps a PPO-family agent's observation normaliser, actor mean and action unnormaliser, clamped to the
env's action bounds; `export_graph` writes it with a dynamic batch and metadata; `check_onnx` compares
onnxruntime's actions with torch's on observations that `record_observations` records from the env."""

from __future__ import annotations

import logging
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import nn

from mimickit.util.errors import MimicKitError

OBS_NAME, ACTION_NAME = "obs", "action"
CHECK_STEPS = 64  # env steps of recorded observations per check
CHECK_RTOL = 1e-5  # of max(largest |action|, 1): float32 kernels differ in summation order only


class PolicyGraph(nn.Module):
    """obs [N, obs_dim] → clamp(unnormalise(actor mean(normalise(obs))), low, high) [N, A]: the env's
    deterministic PD targets. Holds the agent's own normalisers and model (no copy)."""

    def __init__(self, agent: Any, action_low: torch.Tensor, action_high: torch.Tensor):
        super().__init__()
        self.obs_norm, self.model, self.a_norm = agent._obs_norm, agent._model, agent._a_norm
        self.register_buffer("action_low", action_low.detach().clone().float())
        self.register_buffer("action_high", action_high.detach().clone().float())

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        norm_a = self.model.eval_actor(self.obs_norm.normalize(obs)).mode
        return torch.clamp(self.a_norm.unnormalize(norm_a), self.action_low, self.action_high)


@dataclass(frozen=True)
class CheckResult:
    """onnxruntime against torch on `samples` recorded observations: the largest |difference| and the
    largest |action| it is measured against."""

    samples: int
    max_abs_diff: float
    max_abs_action: float

    @property
    def passed(self) -> bool:
        return self.max_abs_diff <= CHECK_RTOL * max(self.max_abs_action, 1.0)


def policy_graph(env: Any, agent: Any) -> PolicyGraph:
    """The graph of a loaded policy; MimicKitError for a policy that needs more than observations."""
    from mimickit.learning.ppo_agent import PPOAgent

    if not isinstance(agent, PPOAgent):
        raise MimicKitError(f"{type(agent).__name__}: ONNX export covers the PPO-family agents (PPO, AWR, AMP, ADD)")
    if type(agent)._eval_policy is not PPOAgent._eval_policy:
        raise MimicKitError(
            f"{type(agent).__name__}: its policy also takes a latent; ONNX export takes observations only"
        )
    space = env.get_action_space()
    return PolicyGraph(agent, torch.as_tensor(space.low), torch.as_tensor(space.high)).eval()


def export_graph(graph: PolicyGraph, obs_dim: int, out: Path, metadata: dict[str, str]) -> None:
    """Write the graph with a dynamic batch dimension and `metadata` as the model's metadata_props."""
    import onnx

    example = torch.zeros(2, obs_dim)
    batch = torch.export.Dim("batch", min=1)
    with torch.no_grad(), _quiet_exporter():
        program = torch.onnx.export(
            graph, (example,), input_names=[OBS_NAME], output_names=[ACTION_NAME],
            dynamic_shapes={"obs": {0: batch}}, dynamo=True, verbose=False,
        )  # fmt: skip
    model = program.model_proto
    for key, value in metadata.items():
        model.metadata_props.add(key=key, value=value)
    onnx.checker.check_model(model)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    onnx.save(model, str(tmp))
    tmp.replace(out)


@contextmanager
def _quiet_exporter() -> Iterator[None]:
    """The exporter logs that torchvision's operators are skipped and warns about its own deprecations:
    nothing a user of this command can act on."""
    log = logging.getLogger("torch.onnx")
    level = log.level
    log.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)
            yield
    finally:
        log.setLevel(level)


def record_observations(env: Any, agent: Any, steps: int = CHECK_STEPS) -> torch.Tensor:
    """Observations [steps × num_envs, obs_dim] of the env driven by the policy's deterministic actions
    (resets included, as `mimickit test` plays it)."""
    obs, _ = env.reset()
    rows = []
    with torch.no_grad():
        for _ in range(steps):
            rows.append(obs.clone())
            obs, _, done, _ = env.step(agent.compute_action(obs, deterministic=True))
            ended = torch.nonzero(done).flatten()
            if len(ended):
                obs, _ = env.reset(ended)
    return torch.cat(rows)


def check_onnx(onnx_file: Path, graph: PolicyGraph, obs: torch.Tensor, agent: Any) -> CheckResult:
    """onnxruntime's actions for `obs` against torch's (`agent.compute_action`, clamped to the bounds)."""
    import onnxruntime as ort

    with torch.no_grad():
        ref = torch.clamp(agent.compute_action(obs, deterministic=True), graph.action_low, graph.action_high)
    session = ort.InferenceSession(str(onnx_file), providers=["CPUExecutionProvider"])
    (got,) = session.run([ACTION_NAME], {OBS_NAME: obs.numpy().astype("float32")})
    diff = float((torch.from_numpy(got) - ref).abs().max())
    return CheckResult(len(obs), diff, float(ref.abs().max()))


def graph_metadata(env: Any, arg_file: str | Path, model_file: str | Path) -> dict[str, str]:
    """The model's metadata_props: what a loop outside MimicKit needs to feed the graph and step the robot."""
    obs_dim, action_dim = env.get_obs_space().shape[0], env.get_action_space().shape[0]
    return {
        "obs_dim": str(obs_dim),
        "action_dim": str(action_dim),
        "env_name": str(env.config.env_name),
        "control_freq": f"{1.0 / env.engine.get_timestep():g}",
        "arg_file": Path(arg_file).name,
        "model_file": Path(model_file).name,
        "action": "PD targets (clamped to the env's action bounds)",
    }
