"""SMP (the reference's SMPAgent): PPO whose reward mixes the task's with a frozen TinyMDM prior's SDS score.
A small prior is trained here on the project's own squat clip (`mimickit train-prior`, a few iterations);
the reward is checked against the reference's formula on the same SDS losses, and the agent trains with
generative state initialisation (GSI) on MuJoCo, saves the prior inside its checkpoint and loads it back.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import yaml

pytest.importorskip("diffusers")

from mimickit.envs.env_builder import build_env_from_configs, load_env_configs  # noqa: E402
from mimickit.envs.smp_env import SMPEnv  # noqa: E402
from mimickit.learning.agent_builder import build_agent_from_config, load_agent_config  # noqa: E402
from mimickit.learning.agent_config import SMPAgentConfig  # noqa: E402
from mimickit.learning.normalizer import DiffNormalizer  # noqa: E402
from mimickit.learning.smp_agent import calc_smp_rewards  # noqa: E402
from mimickit.learning.tinymdm.tinymdm_model import load_prior  # noqa: E402
from mimickit.tools.train_prior import train_prior  # noqa: E402
from mimickit.util.errors import MimicKitError  # noqa: E402
from mimickit.util.paths import PROJECT_DATA_DIR, PROJECT_ROOT  # noqa: E402
from tests.learning.conftest import ppo_config_dict  # noqa: E402

ENGINE = PROJECT_DATA_DIR / "engines/mujoco_engine.yaml"
SMP_ENV = PROJECT_DATA_DIR / "envs/smp_humanoid_env.yaml"
SQUAT = PROJECT_DATA_DIR / "motions/humanoid_demo_squat.pkl"
NUM_ENVS = 4


@pytest.fixture(scope="module")
def prior_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A one-layer prior of the SMP humanoid env's disc obs on the squat clip, 20 iterations."""
    raw = yaml.safe_load((PROJECT_DATA_DIR / "priors/tinymdm_single_clip.yaml").read_text())
    raw.update(num_layers=1, num_attention_heads=2, attention_head_dim=16, batch_size=32, num_samples_stat=500)
    raw.update(model_ema_update_after=0, motion_file=str(SQUAT), output_iter=10)
    d = tmp_path_factory.mktemp("prior")
    (d / "prior.yaml").write_text(yaml.safe_dump(raw))
    train_prior(d / "prior.yaml", d / "out", max_iterations=20, device="cpu", seed=0, log=lambda _: None)
    return d / "out"


def make_env(**overrides: object) -> SMPEnv:
    env_cfg, engine_cfg = load_env_configs(SMP_ENV, ENGINE, SQUAT)
    env = build_env_from_configs(env_cfg.model_copy(update=overrides), engine_cfg, NUM_ENVS)
    assert isinstance(env, SMPEnv)
    return env


def smp_config(prior: Path, **overrides: object) -> SMPAgentConfig:
    fields = {
        "agent_name": "SMP", "smp_prior_cfg": str(prior / "diffusion_config.yaml"),
        "smp_prior_model": str(prior / "model.pt"), "smp_eval_batch_size": 48, "sds_loss_scale": 6,
        "diffusion_steps": [22, 15, 8], "task_reward_weight": 0.0, "smp_reward_weight": 1.0,
    }  # fmt: skip
    return SMPAgentConfig(**ppo_config_dict(**{**fields, "steps_per_iter": 8, **overrides}))


def test_the_reward_is_the_reference_formula_of_the_sds_losses(prior_dir: Path) -> None:
    """r = exp(−scale · mean_t(loss_t / max(mean |loss_t|, 1e-4))) · reward_scale, the losses those of the
    prior's ESM_SDS_loss with the same noise (seeded), evaluated in batches."""
    prior = load_prior(prior_dir / "diffusion_config.yaml", prior_dir / "model.pt")
    x = torch.randn(10, prior.input_dim, generator=torch.Generator().manual_seed(1))
    steps = [22, 15, 8]
    norm = DiffNormalizer((3,))
    norm.record(torch.tensor([[0.5, 2.0, 4e-5]]))  # the third below min_diff: divided by 1e-4
    norm.update()
    torch.manual_seed(5)
    expected_losses = torch.cat([prior.ESM_SDS_loss(b, steps) for b in x.split(4)])
    scaled = expected_losses / torch.tensor([0.5, 2.0, 1e-4])
    expected = torch.exp(-6.0 * scaled.mean(dim=-1)) * 0.7
    torch.manual_seed(5)
    r, loss = calc_smp_rewards(prior, norm, x, steps, 6.0, 0.7, batch_size=4)
    torch.testing.assert_close(r, expected)
    torch.testing.assert_close(loss, expected_losses.mean(dim=-1))
    # Recording feeds the running means (the agent's, while sds_normalizer_samples is not reached).
    torch.manual_seed(5)
    calc_smp_rewards(prior, norm, x, steps, 6.0, batch_size=4, record=True)
    norm.update()
    old = torch.tensor([0.5, 2.0, 4e-5])
    torch.testing.assert_close(norm.state_dict()["_mean_abs"], (old + 10 * expected_losses.abs().mean(0)) / 11)


def test_smp_trains_with_gsi_and_keeps_its_prior_in_the_checkpoint(prior_dir: Path, tmp_path: Path) -> None:
    env = make_env()
    config = smp_config(
        prior_dir, enable_gsi=True, gsi_iters=1, gsi_sampler="ddim", gsi_inference_steps=4, gsi_buffer_size=64,
        gsi_regen_num_motions=32, gsi_batch_size=16,
    )  # fmt: skip
    torch.manual_seed(0)
    agent = build_agent_from_config(config, env, "cpu")
    buffer = env.get_gsi_buffer()
    assert env.has_gsi_buffer() and len(buffer) == 64  # filled from the prior before training

    def stored() -> torch.Tensor:  # the buffer's root heights, in order
        return buffer.sample(64)["root_pos"][..., 2].flatten().sort().values

    before = stored()
    agent.train_model(2 * NUM_ENVS * 8, tmp_path)
    assert not torch.equal(stored(), before)  # refilled after iterations 0 and 1 (gsi_iters 1)
    rows = [json.loads(line) for line in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    assert len(rows) == 2
    for row in rows:  # a 20-iteration prior scores little of what it sees, but a score in [0, 1]
        assert 0 <= row["smp_reward_mean"] <= 1 and row["sds_loss_mean"] > 0 and row["smp_reward_std"] >= 0
    state = torch.load(tmp_path / "model.pt", weights_only=True)
    assert any(k.startswith("_prior_model.dmodel.") for k in state) and "_sds_normalizer._mean_abs" in state
    assert int(state["_sds_normalizer._count"]) == 2 * NUM_ENVS * 8  # both iterations' losses recorded

    again = build_agent_from_config(smp_config(prior_dir), make_env(), "cpu")
    again.load(tmp_path / "model.pt")
    for k, v in again.state_dict().items():
        torch.testing.assert_close(v, state[k], msg=k)


def test_a_prior_of_other_disc_obs_is_one_line(prior_dir: Path) -> None:
    with pytest.raises(MimicKitError, match=r"disc_dof_vel_obs False, env True") as e:
        build_agent_from_config(smp_config(prior_dir), make_env(disc_dof_vel_obs=True), "cpu")
    assert "\n" not in str(e.value)


def test_a_diffusion_step_beyond_the_prior_is_one_line(prior_dir: Path) -> None:
    with pytest.raises(MimicKitError, match=r"diffusion_steps: 50 is outside the prior's 0\.\.49"):
        build_agent_from_config(smp_config(prior_dir, diffusion_steps=[50]), make_env(), "cpu")


def test_gsi_sizes_must_nest() -> None:
    with pytest.raises(ValueError, match="gsi_buffer_size must be >= gsi_regen_num_motions"):
        smp_config(Path("p"), gsi_buffer_size=16, gsi_regen_num_motions=32, gsi_batch_size=16)


@pytest.mark.parametrize("name", ["smp_humanoid_agent.yaml", "smp_task_humanoid_agent.yaml"])
def test_the_shipped_smp_yamls_load(name: str) -> None:
    config = load_agent_config(PROJECT_DATA_DIR / "agents" / name)
    assert isinstance(config, SMPAgentConfig) and config.diffusion_steps == [22, 15, 8]


SMP_ARG_FILES = ["smp_humanoid_args.txt", "smp_location_humanoid_args.txt", "smp_steering_humanoid_args.txt",
                 "smp_dodgeball_humanoid_args.txt"]  # fmt: skip


@pytest.mark.integration
@pytest.mark.parametrize("arg_file", SMP_ARG_FILES)
def test_each_smp_arg_file_trains_two_iterations_on_the_shipped_prior(arg_file: str, tmp_path: Path, test_data) -> None:
    """MimicKit's SMP arg files' counterparts, through `mimickit train` with 2 envs: two iterations, the
    prior's reward logged, a checkpoint that holds the shipped prior."""
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "mimickit.cli", "train", "--arg_file", f"args/{arg_file}", "--data_dir",
           str(test_data), "--num_envs", "2", "--max_samples", "128", "--out_dir", str(out),
           "--rand_seed", "0"]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=PROJECT_ROOT)
    assert done.returncode == 0, done.stderr[-2000:]
    rows = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert [r["samples"] for r in rows] == [64, 128]
    assert all(0 <= r["smp_reward_mean"] <= 1 and r["sds_loss_mean"] > 0 for r in rows)
    state = torch.load(out / "model.pt", weights_only=True)
    prior_file = load_agent_config(out / "agent_config.yaml").smp_prior_model
    shipped = torch.load(PROJECT_DATA_DIR.parent / prior_file, weights_only=True)
    for k, v in shipped.items():
        torch.testing.assert_close(state[f"_prior_model.{k}"], v, msg=k)
