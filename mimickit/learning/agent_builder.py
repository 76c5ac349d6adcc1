"""Load an agent yaml and build its agent, choosing the class by `agent_name` from the `AGENTS` table below
(where a new agent is registered: its config class from `agent_config` and its "module:Class", one line).

No agent file (None or "") gives the `DummyAgent` (zero actions), as the reference.
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch

from mimickit.envs.base_env import BaseEnv
from mimickit.learning import mp_util
from mimickit.learning.agent_config import (
    ADDAgentConfig,
    AMPAgentConfig,
    ASEAgentConfig,
    AWRAgentConfig,
    BaseAgentConfig,
    DummyAgentConfig,
    LCPAgentConfig,
    PPOAgentConfig,
    SMPAgentConfig,
)
from mimickit.learning.base_agent import BaseAgent
from mimickit.util.config import load_yaml, parse_config
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import DataPaths
from mimickit.util.registry import Entry, Registry

AGENTS: Registry[BaseAgentConfig, BaseAgent] = Registry(
    "agent",
    "mimickit.learning.base_agent:BaseAgent",
    {
        "PPO": Entry(PPOAgentConfig, "mimickit.learning.ppo_agent:PPOAgent"),
        "AWR": Entry(AWRAgentConfig, "mimickit.learning.awr_agent:AWRAgent"),
        "AMP": Entry(AMPAgentConfig, "mimickit.learning.amp_agent:AMPAgent"),
        "ADD": Entry(ADDAgentConfig, "mimickit.learning.add_agent:ADDAgent"),
        "ASE": Entry(ASEAgentConfig, "mimickit.learning.ase_agent:ASEAgent"),
        "LCP": Entry(LCPAgentConfig, "mimickit.learning.ppo_agent:PPOAgent"),
        "SMP": Entry(SMPAgentConfig, "mimickit.learning.smp_agent:SMPAgent"),
        "Dummy": Entry(DummyAgentConfig, "mimickit.learning.dummy_agent:DummyAgent"),
    },
)
"""Every agent by its yaml `agent_name`: `load_agent_config` and the builders below use this table."""


def load_agent_config(path: str | Path) -> BaseAgentConfig:
    """Read an agent yaml and validate it against the config class of its `agent_name`."""
    data = load_yaml(path)
    name = data.get("agent_name")
    if name is None:
        raise MimicKitError(f"{path}: missing required key 'agent_name'")
    if name not in AGENTS:
        raise MimicKitError(f"{path}: key 'agent_name': {AGENTS.unknown(name)}")
    return parse_config(AGENTS.config_class(name), data, path)


def build_agent(
    agent_file: str | Path | None,
    env: BaseEnv,
    device: torch.device | str = "cpu",
    verbose: bool = True,
    data_paths: DataPaths | None = None,
) -> BaseAgent:
    """The agent described by `agent_file` for `env`, on `device`; prints the parameter count (rank 0).
    A `data/agents/...` name is found by `data_paths`, by default the env's."""
    paths = data_paths or env.data_paths
    config = load_agent_config(paths.resolve(agent_file)) if agent_file else DummyAgentConfig()
    agent = build_agent_from_config(config, env, device)
    if verbose and mp_util.is_root_proc():
        print(f"Total parameter count: {agent.get_num_params()}", file=sys.stderr, flush=True)
    return agent


def build_agent_from_config(config: BaseAgentConfig, env: BaseEnv, device: torch.device | str = "cpu") -> BaseAgent:
    """The agent class registered for `config.agent_name` (`AGENTS`), imported only now."""
    if config.agent_name not in AGENTS:  # a config built in code; load_agent_config refuses these itself
        raise MimicKitError(f"agent config: key 'agent_name': {AGENTS.unknown(config.agent_name)}")
    return AGENTS.resolve(config.agent_name)(config, env, device)
