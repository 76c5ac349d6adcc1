"""Diagonal Gaussian policy head, as the reference's (same init, same checkpoint keys).

`GaussianDiagHead` maps features [B, F] to a `GaussianDiag` over normalised actions [B, A]:
the mean is a Linear (`_mean_net`) with weights U(−s, s) and zero bias; the log-std (`_logstd_net`) is
FIXED (a non-trainable parameter log(action_std)), CONSTANT (a trainable vector) or VARIABLE (a
Linear with weights U(−s, s) and bias log(action_std)).
"""

from __future__ import annotations

import math
from enum import Enum

import torch
from torch import nn

_LOG_2PI = math.log(2.0 * math.pi)


class StdType(str, Enum):
    FIXED = "FIXED"
    CONSTANT = "CONSTANT"
    VARIABLE = "VARIABLE"


class GaussianDiag:
    """N(mean, diag(exp(logstd)²)); mean and logstd [B, A] (logstd may broadcast from [A])."""

    def __init__(self, mean: torch.Tensor, logstd: torch.Tensor) -> None:
        self.mean = mean
        self.logstd = logstd.expand_as(mean)
        self.std = torch.exp(self.logstd)

    @property
    def mode(self) -> torch.Tensor:
        """The most likely action, the mean [B, A]."""
        return self.mean

    def sample(self) -> torch.Tensor:
        """μ + σ·ε, [B, A]."""
        return self.mean + self.std * torch.randn_like(self.mean)

    def log_prob(self, x: torch.Tensor) -> torch.Tensor:
        """log density of x [B, A], summed over action dims → [B]."""
        z = (x - self.mean) / self.std
        return (-0.5 * z.square() - self.logstd - 0.5 * _LOG_2PI).sum(dim=-1)

    def entropy(self) -> torch.Tensor:
        """[B]."""
        return (self.logstd + 0.5 * (1.0 + _LOG_2PI)).sum(dim=-1)

    def kl(self, other: GaussianDiag) -> torch.Tensor:
        """KL(self ‖ other), [B]."""
        var_ratio = (self.std / other.std).square()
        mean_term = ((self.mean - other.mean) / other.std).square()
        return 0.5 * (var_ratio + mean_term - 1.0 - torch.log(var_ratio)).sum(dim=-1)

    def param_reg(self) -> torch.Tensor:
        """Σ μ², [B] (the action_reg_weight penalty)."""
        return self.mean.square().sum(dim=-1)


class GaussianDiagHead(nn.Module):
    def __init__(
        self,
        in_size: int,
        action_size: int,
        std_type: StdType | str,
        init_std: float,
        init_output_scale: float,
    ) -> None:
        super().__init__()
        self._std_type = StdType(std_type)
        self._mean_net = nn.Linear(in_size, action_size)
        nn.init.uniform_(self._mean_net.weight, -init_output_scale, init_output_scale)
        nn.init.zeros_(self._mean_net.bias)

        log_std = math.log(init_std)
        self._logstd_net: nn.Parameter | nn.Linear
        if self._std_type == StdType.VARIABLE:
            self._logstd_net = nn.Linear(in_size, action_size)
            nn.init.uniform_(self._logstd_net.weight, -init_output_scale, init_output_scale)
            nn.init.constant_(self._logstd_net.bias, log_std)
        else:
            trainable = self._std_type == StdType.CONSTANT
            self._logstd_net = nn.Parameter(torch.full((action_size,), log_std), requires_grad=trainable)

    def forward(self, x: torch.Tensor) -> GaussianDiag:
        """Features [B, in_size] → distribution over [B, action_size]."""
        mean = self._mean_net(x)
        logstd = self._logstd_net(x) if isinstance(self._logstd_net, nn.Linear) else self._logstd_net
        return GaussianDiag(mean, logstd)
