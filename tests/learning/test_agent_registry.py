"""The agent registry (`AGENTS`): every name loads its config class from a yaml and resolves its agent class
(the builder builds from the same entry); an unknown name is one error line naming the nearest. What is
checked is derived from the registry (tests/util/registry_checks.py): a new agent is checked without editing
this."""

from __future__ import annotations

from pathlib import Path

import pytest

from mimickit.learning.agent_builder import AGENTS, build_agent_from_config, load_agent_config
from mimickit.learning.agent_config import DummyAgentConfig
from mimickit.learning.base_agent import BaseAgent
from mimickit.util.errors import MimicKitError
from tests.learning.toy_env import TargetReachEnv
from tests.util.config_errors import load_error
from tests.util.registry_checks import shipped_yamls, supported_list, undocumented


def shipped_agent_yamls() -> dict[str, Path]:
    """The first shipped agent yaml of each agent_name."""
    return shipped_yamls("agents", "agent_name")


def test_every_shipped_agent_yaml_is_registered_and_every_agent_documented():
    assert set(shipped_agent_yamls()) <= set(AGENTS.names)
    assert not undocumented(AGENTS.names)


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
    assert (
        str(e.value)
        == f"{f}: key 'agent_name': agent 'PPP' is not supported; {supported_list(AGENTS)} (did you mean 'PPO'?)"
    )


@pytest.mark.parametrize(
    "value, needle",
    [
        ("Zebra", f"agent 'Zebra' is not supported; {supported_list(AGENTS)}"),
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
