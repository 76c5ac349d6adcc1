"""Build an agent from an agent yaml, choosing the class by `agent_name` from the `AGENTS` table in
`agent_config` (where a new agent is registered: one line there, nothing here).

No agent file (None or "") gives the `DummyAgent` (zero actions), as the reference.
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch

from mimickit.envs.base_env import BaseEnv
from mimickit.learning import mp_util
from mimickit.learning.agent_config import AGENTS, BaseAgentConfig, DummyAgentConfig, load_agent_config
from mimickit.learning.base_agent import BaseAgent
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import DataPaths


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
