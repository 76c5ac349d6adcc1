"""Build an agent from an agent yaml, choosing the class by `agent_name` (spec §1.3).

No agent file (None or "") gives the `DummyAgent` (zero actions), as the reference.
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch

from mimickit.envs.base_env import BaseEnv
from mimickit.learning import mp_util
from mimickit.learning.agent_config import BaseAgentConfig, DummyAgentConfig, load_agent_config
from mimickit.learning.base_agent import BaseAgent
from mimickit.util.paths import resolve_data_path


def build_agent(
    agent_file: str | Path | None, env: BaseEnv, device: torch.device | str = "cpu", verbose: bool = True
) -> BaseAgent:
    """The agent described by `agent_file` for `env`, on `device`; prints the parameter count (rank 0)."""
    config = load_agent_config(resolve_data_path(agent_file)) if agent_file else DummyAgentConfig()
    agent = build_agent_from_config(config, env, device)
    if verbose and mp_util.is_root_proc():
        print(f"Total parameter count: {agent.get_num_params()}", file=sys.stderr, flush=True)
    return agent


def build_agent_from_config(config: BaseAgentConfig, env: BaseEnv, device: torch.device | str = "cpu") -> BaseAgent:
    if config.agent_name == "PPO":
        from mimickit.learning.ppo_agent import PPOAgent as cls
    elif config.agent_name == "AWR":
        from mimickit.learning.awr_agent import AWRAgent as cls
    elif config.agent_name == "AMP":
        from mimickit.learning.amp_agent import AMPAgent as cls
    elif config.agent_name == "ASE":
        from mimickit.learning.ase_agent import ASEAgent as cls
    elif config.agent_name == "ADD":
        from mimickit.learning.add_agent import ADDAgent as cls
    elif config.agent_name == "Dummy":
        from mimickit.learning.dummy_agent import DummyAgent as cls
    else:  # load_agent_config already refused other names
        raise AssertionError(config.agent_name)
    return cls(config, env, device)
