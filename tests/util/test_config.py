import pytest

from mimickit.util.config import ConfigModel, load_config
from mimickit.util.errors import MimicKitError


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
    f = tmp_path / "agent.yaml"
    f.write_text(text)
    with pytest.raises(MimicKitError) as e:
        load_config(Agent, f)
    assert needle in str(e.value)
    assert "agent.yaml" in str(e.value)


def test_missing_file(tmp_path):
    with pytest.raises(MimicKitError, match="not found"):
        load_config(Agent, tmp_path / "none.yaml")
