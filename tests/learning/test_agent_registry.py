"""The agent registry (`AGENTS`): every name loads its config class from a yaml and resolves its agent class
(the builder builds from the same entry); an unknown name is one error line naming the nearest."""

from __future__ import annotations

from pathlib import Path

import pytest

from mimickit.learning.agent_builder import build_agent_from_config
from mimickit.learning.agent_config import AGENTS, DummyAgentConfig, load_agent_config
from mimickit.learning.base_agent import BaseAgent
from mimickit.util.config import load_yaml
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA_DIR
from tests.learning.toy_env import TargetReachEnv
from tests.util.config_errors import load_error


def shipped_agent_yamls() -> dict[str, Path]:
    """The first shipped agent yaml of each agent_name."""
    found: dict[str, Path] = {}
    for path in sorted((PROJECT_DATA_DIR / "agents").glob("*.yaml")):
        found.setdefault(load_yaml(path)["agent_name"], path)
    return found


def test_the_reference_agent_names_are_registered():
    assert AGENTS.names == ("PPO", "AWR", "AMP", "ADD", "ASE", "Dummy")
    assert set(shipped_agent_yamls()) <= set(AGENTS.names)


@pytest.mark.parametrize("name", AGENTS.names)
def test_every_agent_loads_its_config_class_and_resolves_its_class(tmp_path, name):
    path = shipped_agent_yamls().get(name)
    if path is None:  # Dummy: no shipped yaml, every field has a default
        path = tmp_path / "agent.yaml"
        path.write_text(f"agent_name: {name}\n")
    config = load_agent_config(path)
    assert type(config) is AGENTS.config_class(name) and config.agent_name == name
    cls = AGENTS.resolve(name)
    assert issubclass(cls, BaseAgent) and cls is not BaseAgent


def test_the_builder_builds_the_registered_class():
    agent = build_agent_from_config(DummyAgentConfig(), TargetReachEnv(num_envs=2), "cpu")
    assert type(agent) is AGENTS.resolve("Dummy")


def test_an_unknown_agent_name_is_one_line_naming_the_nearest(tmp_path):
    f = tmp_path / "agent.yaml"
    f.write_text("agent_name: PPP\n")
    with pytest.raises(MimicKitError) as e:
        load_agent_config(f)
    assert str(e.value) == (
        f"{f}: key 'agent_name': agent 'PPP' is not supported; "
        "supported agents: PPO, AWR, AMP, ADD, ASE, Dummy (did you mean 'PPO'?)"
    )


@pytest.mark.parametrize(
    "value, needle",
    [
        ("SMP", "agent 'SMP' is not supported (not ported yet); supported agents: PPO,"),
        ("Zebra", "agent 'Zebra' is not supported; supported agents: PPO, AWR, AMP, ADD, ASE, Dummy"),
        ("[PPO]", "agent ['PPO'] is not supported"),
        ("3", "agent 3 is not supported"),
    ],
)
def test_odd_agent_names_are_one_line(tmp_path, value, needle):
    f, msg = load_error(tmp_path, f"agent_name: {value}\n", load_agent_config, "agent.yaml")
    assert needle in msg and "\n" not in msg
    if value == "Zebra":
        assert "did you mean" not in msg


def test_a_config_built_in_code_with_an_unknown_name_is_refused_by_the_builder():
    with pytest.raises(MimicKitError, match="agent 'Dumy' is not supported.*did you mean 'Dummy'"):
        build_agent_from_config(DummyAgentConfig(agent_name="Dumy"), TargetReachEnv(num_envs=2), "cpu")
