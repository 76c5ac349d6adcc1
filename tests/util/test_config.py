import pytest

from mimickit.util.config import ConfigModel, format_validation_error, load_config, load_yaml_text
from mimickit.util.errors import MimicKitError
from tests.util.config_errors import load_error


class Agent(ConfigModel):
    learning_rate: float
    steps_per_iter: int
    normalize: bool = True


def test_scientific_notation_string_is_a_number(tmp_path):
    f = tmp_path / "a.yaml"
    f.write_text("learning_rate: 1e-4\nsteps_per_iter: 32\n")
    cfg = load_config(Agent, f)
    assert cfg.learning_rate == pytest.approx(1e-4)
    assert cfg.normalize is True


@pytest.mark.parametrize(
    "text, needle",
    [
        ("learning_rate: 1e-4\nsteps_per_iter: 32\nlearnign_rate: 2\n", "unknown key 'learnign_rate'"),
        ("learning_rate: fast\nsteps_per_iter: 32\n", "key 'learning_rate'"),
        ("learning_rate: 0.1\n", "missing required key 'steps_per_iter'"),
        ("learning_rate: [0.1\n", "not valid YAML"),
        ("- 1\n- 2\n", "mapping"),
    ],
)
def test_errors_name_file_and_key(tmp_path, text, needle):
    _, msg = load_error(tmp_path, text, lambda f: load_config(Agent, f), "agent.yaml")
    assert needle in msg and "agent.yaml" in msg


def test_missing_file(tmp_path):
    with pytest.raises(MimicKitError, match="not found"):
        load_config(Agent, tmp_path / "none.yaml")


class Nested(ConfigModel):
    agent: Agent
    name: str = "x"


def test_unknown_nested_key_names_the_nearest_field(tmp_path):
    f = tmp_path / "n.yaml"
    f.write_text("agent: {learning_rate: 1, steps_per_iter: 2, normalise: true}\n")
    with pytest.raises(MimicKitError, match=r"unknown key 'agent.normalise' \(did you mean 'normalize'\?\)"):
        load_config(Nested, f)


def test_nan_and_inf_are_refused_unless_a_field_allows_them(tmp_path):
    f = tmp_path / "a.yaml"
    f.write_text("learning_rate: .nan\nsteps_per_iter: 32\n")
    with pytest.raises(MimicKitError, match="learning_rate"):
        load_config(Agent, f)


def test_alias_expansion_is_counted_not_built():
    # 4 levels of 10 → 10,000 leaves: under the limit, expanded as usual
    text = "a: &a [1,1,1,1,1,1,1,1,1,1]\nb: &b [*a,*a,*a,*a,*a,*a,*a,*a,*a,*a]\n"
    text += "c: &c [*b,*b,*b,*b,*b,*b,*b,*b,*b,*b]\nd: [*c,*c,*c,*c,*c,*c,*c,*c,*c,*c]\n"
    data = load_yaml_text(text)
    assert len(data["d"]) == 10 and sum(len(b) for c in data["d"] for b in c) == 1000
    with pytest.raises(MimicKitError, match="alias bomb"):
        load_yaml_text(text + "e: &e [" + ", ".join(["*c"] * 10) + "]\nf: [" + ", ".join(["*e"] * 30) + "]\n")


def test_validation_error_lists_a_few_problems():
    from pydantic import ValidationError

    class Many(ConfigModel):
        a: int
        b: int
        c: int
        d: int
        e: int
        f: int
        g: int

    with pytest.raises(ValidationError) as e:
        Many.model_validate({})
    msg = format_validation_error(e.value, Many)
    assert msg.count("missing required key") == 5 and msg.endswith("and 2 more problems")


class ListOfAgents(ConfigModel):
    agents: list[Agent]


def test_unknown_key_in_a_list_item_names_the_nearest_field(tmp_path):
    f = tmp_path / "c.yaml"
    f.write_text("agents:\n  - learning_rate: 0.1\n  - lerning_rate: 0.2\n")
    with pytest.raises(MimicKitError, match=r"unknown key 'agents.1.lerning_rate' \(did you mean 'learning_rate'\?\)"):
        load_config(ListOfAgents, f)
