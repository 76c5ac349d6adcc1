import math

import pytest
import torch

from mimickit.envs.base_env import DoneFlags
from mimickit.learning import rl_util
from mimickit.learning.distributions import GaussianDiagHead
from mimickit.learning.experience_buffer import ExperienceBuffer
from mimickit.learning.nets import build_net


def test_td_lambda_return_by_hand():
    # one env, 3 steps, γ = λ = 0.5
    r = torch.tensor([[1.0], [1.0], [1.0]])
    v_next = torch.tensor([[10.0], [20.0], [30.0]])
    done = torch.zeros(3, 1, dtype=torch.long)
    ret = rl_util.compute_td_lambda_return(r, v_next, done, 0.5, 0.5)
    # R2 = 1 + .5·30 = 16; R1 = 1 + .5(.5·20 + .5·16) = 10; R0 = 1 + .5(.5·10 + .5·10) = 6
    assert ret.flatten().tolist() == pytest.approx([6.0, 10.0, 16.0])


def test_td_lambda_return_cuts_the_chain_at_episode_ends():
    r = torch.tensor([[1.0, 1.0], [1.0, 1.0], [1.0, 1.0]])
    v_next = torch.tensor([[10.0, 10.0], [0.0, 20.0], [30.0, 30.0]])  # FAIL row already holds 0
    done = torch.tensor([[0, 0], [DoneFlags.FAIL, DoneFlags.TIME], [0, 0]])
    ret = rl_util.compute_td_lambda_return(r, v_next, done, 0.5, 0.5)
    # env 0: R2 = 16, R1 = 1 + .5·0 = 1 (λ cut), R0 = 1 + .5(.5·10 + .5·1) = 3.75
    # env 1: R2 = 16, R1 = 1 + .5·20 = 11 (TIME bootstraps), R0 = 1 + .5(.5·10 + .5·11) = 6.25
    assert ret[:, 0].tolist() == pytest.approx([3.75, 1.0, 16.0])
    assert ret[:, 1].tolist() == pytest.approx([6.25, 11.0, 16.0])


def test_clipped_surrogate_by_hand():
    ratio = torch.tensor([1.5, 0.5, 1.1, 0.7])
    adv = torch.tensor([2.0, 2.0, -1.0, -1.0])
    # min(Aρ, A·clip(ρ, .8, 1.2)): 2·1.2=2.4 | 2·.5=1.0 | -1.1 vs -1.1 → -1.1 | -.7 vs -.8 → -.8
    loss = rl_util.ppo_surrogate_loss(ratio, adv, 0.2)
    assert loss.item() == pytest.approx(-(2.4 + 1.0 - 1.1 - 0.8) / 4)
    assert rl_util.ppo_clip_frac(ratio, 0.2).item() == pytest.approx(0.75)


def test_action_bound_loss_by_hand():
    mean = torch.tensor([[0.5, -0.9], [1.5, -3.0]])
    loss = rl_util.action_bound_loss(mean)
    assert loss.tolist() == pytest.approx([0.0, 0.25 + 4.0])


def test_awr_weights_are_clipped_not_the_advantages():
    w = rl_util.awr_weights(torch.tensor([-1.0, 0.0, 5.0]), temp=1.0, weight_clip=20.0)
    assert w.tolist() == pytest.approx([math.exp(-1.0), 1.0, 20.0])


def test_gaussian_head_log_prob_entropy_and_init():
    torch.manual_seed(0)
    head = GaussianDiagHead(8, 3, "FIXED", init_std=0.05, init_output_scale=0.01)
    params = dict(head.named_parameters())  # the reference's checkpoint names
    assert not params["_logstd_net"].requires_grad
    assert params["_mean_net.weight"].abs().max() <= 0.01 and torch.all(params["_mean_net.bias"] == 0)
    feats = torch.randn(5, 8)
    dist = head(feats)
    x = dist.sample()
    ref = torch.distributions.Normal(dist.mean, dist.std)
    assert torch.allclose(dist.log_prob(x), ref.log_prob(x).sum(-1), atol=1e-5)
    assert torch.allclose(dist.entropy(), ref.entropy().sum(-1), atol=1e-5)
    variable = GaussianDiagHead(8, 3, "VARIABLE", init_std=0.05, init_output_scale=0.01)
    assert set(dict(variable.named_parameters())) == {
        "_mean_net.weight", "_mean_net.bias", "_logstd_net.weight", "_logstd_net.bias"
    }  # fmt: skip


def test_named_net_layout():
    net, out = build_net("fc_3layers_1024units", 10)
    assert out == 512
    assert [k for k in net.state_dict()] == [f"{i}.{p}" for i in (0, 2, 4) for p in ("weight", "bias")]
    assert all(torch.all(net[i].bias == 0) for i in (0, 2, 4))


def test_experience_buffer_sampling_covers_one_epoch():
    buf = ExperienceBuffer(buffer_length=4, batch_size=3, device="cpu")
    for t in range(4):
        buf.record("x", torch.arange(3) + 10 * t)
        buf.inc()
    assert buf.get_total_samples() == 12 and buf.get_sample_count() == 12
    seen = torch.cat([buf.sample(4)["x"] for _ in range(3)])
    assert sorted(seen.tolist()) == sorted(buf.get_data_flat("x").tolist())
    assert buf.get_data("x")[2].tolist() == [20, 21, 22]
    buf.reset()
    assert buf.get_total_samples() == 12
    buf.clear()
    assert buf.get_total_samples() == 0


def test_exploring_rows_is_none_when_every_row_explored():
    assert rl_util.exploring_rows({"rand_action_mask": torch.ones(5)}) is None
    mask = rl_util.exploring_rows({"rand_action_mask": torch.tensor([1.0, 0.0, 1.0])})
    assert mask.tolist() == [True, False, True]
    x = torch.arange(3.0)
    assert rl_util.select_rows(x, mask).tolist() == [0.0, 2.0]
    assert rl_util.select_rows(x, None) is x


def test_minibatch_rows_match_across_arrays():
    """A minibatch gathers each array when read, all from the same sampled rows."""
    buf = ExperienceBuffer(buffer_length=2, batch_size=4, device="cpu")
    for t in range(2):
        buf.record("x", torch.arange(4.0) + 10 * t)
        buf.record("y", -(torch.arange(4.0) + 10 * t))
        buf.inc()
    batch = buf.sample(5)
    assert set(batch) == {"x", "y"} and len(batch) == 2
    assert torch.equal(batch["y"], -batch["x"]) and batch["x"].shape == (5,)
