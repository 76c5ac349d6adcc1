import pytest

from mimickit.learning.agent_builder import load_agent_config
from mimickit.learning.agent_config import AWRAgentConfig, PPOAgentConfig
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA_DIR
from tests.util.config_errors import load_error


def test_shipped_humanoid_yamls_have_the_reference_values():
    ppo = load_agent_config(PROJECT_DATA_DIR / "agents" / "deepmimic_humanoid_ppo_agent.yaml")
    assert isinstance(ppo, PPOAgentConfig)
    assert ppo.actor_optimizer.type == "SGD" and ppo.actor_optimizer.learning_rate == pytest.approx(1e-4)
    assert ppo.model.actor_net == "fc_2layers_1024units" and ppo.model.action_std == 0.05
    assert (ppo.steps_per_iter, ppo.actor_batch_size, ppo.critic_batch_size) == (32, 4, 2)
    assert ppo.normalizer_samples == 1e8 and ppo.ppo_clip_ratio == 0.2 and ppo.norm_adv_clip == 4.0
    awr = load_agent_config(PROJECT_DATA_DIR / "agents" / "deepmimic_humanoid_awr_agent.yaml")
    assert isinstance(awr, AWRAgentConfig)
    assert (awr.awr_temp, awr.a_weight_clip) == (1.0, 20.0)


@pytest.mark.parametrize(
    "text, needle",
    [
        ("agent_name: PPO\nmodel: {}\n", "missing required key"),
        ("agent_name: SMP\n", "missing required key"),
        ("agent_name: SAC\n", "is not supported"),
        ("discount: 0.9\n", "missing required key 'agent_name'"),
    ],
)
def test_bad_agent_yaml_names_file_and_key(tmp_path, text, needle):
    f, msg = load_error(tmp_path, text, load_agent_config, "agent.yaml")
    assert str(f) in msg and needle in msg


def test_unknown_key_is_refused(tmp_path):
    text = (PROJECT_DATA_DIR / "agents" / "deepmimic_humanoid_ppo_agent.yaml").read_text()
    f = tmp_path / "agent.yaml"
    f.write_text(text + "ppo_clip_ratoi: 0.3\n")
    with pytest.raises(MimicKitError, match="unknown key 'ppo_clip_ratoi'"):
        load_agent_config(f)
