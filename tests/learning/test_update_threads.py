"""The update's thread settings and gradient handling keep the weights bit for bit."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from mimickit.learning.agent_config import OptimizerConfig
from mimickit.learning.mp_optimizer import MPOptimizer
from mimickit.learning.update_threads import mkl_local_threads_available, update_threads
from mimickit.util.threads import torch_threads


def _train(steps: int = 6) -> dict[str, torch.Tensor]:
    """SGD on the shapes of the CPU agent's actor (a 28×256 output from batches of 1024)."""
    torch.manual_seed(0)
    net = nn.Sequential(nn.Linear(464, 256), nn.ReLU(), nn.Linear(256, 28))
    opt = MPOptimizer(OptimizerConfig(type="SGD", learning_rate=1e-2), net.parameters())
    for _ in range(steps):
        x = torch.randn(1024, 464)
        opt.step((net(x) - 0.5).square().mean())
    return {k: v.clone() for k, v in net.state_dict().items()}


def test_update_threads_sets_one_torch_thread_and_restores():
    with torch_threads(2):
        with update_threads():
            assert torch.get_num_threads() == (1 if mkl_local_threads_available() else 2)
        assert torch.get_num_threads() == 2


@pytest.mark.skipif(not mkl_local_threads_available(), reason="torch without MKL's thread-local setting")
def test_update_threads_gives_the_all_threads_weights():
    with torch_threads(2):
        ref = _train()
        with update_threads():
            split = _train()
    assert all(torch.equal(ref[k], split[k]) for k in ref)


def test_parameter_the_loss_skips_keeps_its_momentum():
    """A parameter that had a gradient and is not reached by the next loss gets zeros (momentum still
    moves it), as when gradients were zeroed in place."""
    a = nn.Parameter(torch.ones(3))
    b = nn.Parameter(torch.ones(3))
    opt = MPOptimizer(OptimizerConfig(type="SGD", learning_rate=0.1), [a, b])
    opt.step((a + b).sum())
    after_first = b.detach().clone()
    opt.step(a.sum())  # b unreached: momentum 0.9 of its last step moves it again
    assert b.grad is not None and torch.equal(b.grad, torch.zeros(3))
    assert torch.allclose(after_first - b.detach(), torch.full((3,), 0.09))
