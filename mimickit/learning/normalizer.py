"""Running mean/std normaliser, and the mean-|x| normaliser of differences ADD uses (both as the reference's).

`record(x)` accumulates count, Σx and Σx² of new samples; `update()` sums those over processes and
merges them into the cumulative mean and variance, weighted by counts (no EMA, no decay);
`normalize(x)` = clip((x − mean) / std, ±clip). The state lives in buffers `_count` (int64 [1]),
`_mean` [*shape] and `_std` [*shape], so a state_dict has the reference's key names.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from mimickit.learning import mp_util


class Normalizer(nn.Module):
    _count: torch.Tensor
    _mean: torch.Tensor
    _std: torch.Tensor

    def __init__(
        self,
        shape: tuple[int, ...],
        device: torch.device | str = "cpu",
        init_mean: torch.Tensor | None = None,
        init_std: torch.Tensor | None = None,
        min_std: float = 1e-4,
        clip: float = math.inf,
        dtype: torch.dtype = torch.float32,
    ) -> None:
        super().__init__()
        self._shape = tuple(shape)
        self._min_std = min_std
        self._clip = clip
        mean = torch.zeros(self._shape, dtype=dtype) if init_mean is None else init_mean.to(dtype).clone()
        std = torch.ones(self._shape, dtype=dtype) if init_std is None else init_std.to(dtype).clone()
        self.register_buffer("_count", torch.zeros(1, dtype=torch.long))
        self.register_buffer("_mean", mean)
        self.register_buffer("_std", std)
        self.to(device)
        self._reset_new_stats()

    def record(self, x: torch.Tensor) -> None:
        """Accumulate samples x [..., *shape] (all leading dims are samples) for the next `update()`."""
        x = x.detach().reshape(-1, *self._shape).to(device=self._new_sum.device, dtype=torch.float64)
        self._new_count += x.shape[0]
        self._new_sum += x.sum(dim=0)
        self._new_sum_sq += x.square().sum(dim=0)

    def update(self) -> None:
        """Merge everything recorded since the last update (over all processes) into mean and std."""
        stats = torch.cat([self._new_count.reshape(1), self._new_sum.reshape(-1), self._new_sum_sq.reshape(-1)])
        stats = stats.to(self._mean.device)
        mp_util.reduce_inplace_sum(stats)
        n = self._mean.numel()
        new_count = stats[0]
        if new_count.item() > 0:
            new_mean = stats[1 : 1 + n].reshape(self._shape) / new_count
            new_sq = stats[1 + n :].reshape(self._shape) / new_count
            old_count = self._count.to(torch.float64)
            total = old_count + new_count
            w_old, w_new = old_count / total, new_count / total
            mean = self._mean.to(torch.float64)
            old_sq = self._std.to(torch.float64).square() + mean.square()
            merged_mean = w_old * mean + w_new * new_mean
            merged_sq = w_old * old_sq + w_new * new_sq
            var = (merged_sq - merged_mean.square()).clamp_min(self._min_std**2)
            self._count += int(new_count.item())
            self._mean.copy_(merged_mean.to(self._mean.dtype))
            self._std.copy_(var.sqrt().to(self._std.dtype))
        self._reset_new_stats()

    def normalize(self, x: torch.Tensor) -> torch.Tensor:
        """(x − mean) / std clipped to ±clip; x [..., *shape]."""
        norm = (x - self._mean) / self._std
        if math.isfinite(self._clip):
            norm = norm.clamp(-self._clip, self._clip)
        return norm.to(self._mean.dtype)

    def unnormalize(self, norm_x: torch.Tensor) -> torch.Tensor:
        """norm_x · std + mean; norm_x [..., *shape]."""
        return (norm_x * self._std + self._mean).to(self._mean.dtype)

    def get_shape(self) -> tuple[int, ...]:
        return self._shape

    def get_count(self) -> int:
        return int(self._count.item())

    def get_mean(self) -> torch.Tensor:
        return self._mean

    def get_std(self) -> torch.Tensor:
        return self._std

    def set_mean_std(self, mean: torch.Tensor, std: torch.Tensor) -> None:
        with torch.no_grad():
            self._mean.copy_(mean)
            self._std.copy_(std)

    def _reset_new_stats(self) -> None:
        device = self._mean.device
        self._new_count = torch.zeros((), dtype=torch.float64, device=device)
        self._new_sum = torch.zeros(self._shape, dtype=torch.float64, device=device)
        self._new_sum_sq = torch.zeros(self._shape, dtype=torch.float64, device=device)


class DiffNormalizer(nn.Module):
    """Scale-only normaliser of differences (ADD, as the reference's): x / max(mean |x|, min_diff), clipped.

    Differences are centred at 0 by construction (0 = a perfect match), so there is no shift: a mean
    would move the zero vector the discriminator learns as "demo". `record` accumulates count and Σ|x|;
    `update` merges them over processes into the running mean |x| weighted by counts. The state lives
    in buffers `_count` (int64 [1]) and `_mean_abs` [*shape] (starts at 1: the first iteration sees
    raw differences), the reference's key names.
    """

    _count: torch.Tensor
    _mean_abs: torch.Tensor

    def __init__(
        self,
        shape: tuple[int, ...],
        device: torch.device | str = "cpu",
        min_diff: float = 1e-4,
        clip: float = math.inf,
        dtype: torch.dtype = torch.float32,
    ) -> None:
        super().__init__()
        self._shape = tuple(shape)
        self._min_diff = min_diff
        self._clip = clip
        self.register_buffer("_count", torch.zeros(1, dtype=torch.long))
        self.register_buffer("_mean_abs", torch.ones(self._shape, dtype=dtype))
        self.to(device)
        self._reset_new_stats()

    def record(self, x: torch.Tensor) -> None:
        """Accumulate differences x [..., *shape] (all leading dims are samples) for the next `update()`."""
        x = x.detach().reshape(-1, *self._shape).to(device=self._new_sum_abs.device, dtype=torch.float64)
        self._new_count += x.shape[0]
        self._new_sum_abs += x.abs().sum(dim=0)

    def update(self) -> None:
        """Merge everything recorded since the last update (over all processes) into mean |x|."""
        stats = torch.cat([self._new_count.reshape(1), self._new_sum_abs.reshape(-1)]).to(self._mean_abs.device)
        mp_util.reduce_inplace_sum(stats)
        new_count = stats[0]
        if new_count.item() > 0:
            new_mean_abs = stats[1:].reshape(self._shape) / new_count
            total = self._count.to(torch.float64) + new_count
            w_old = self._count.to(torch.float64) / total
            merged = w_old * self._mean_abs.to(torch.float64) + (1.0 - w_old) * new_mean_abs
            self._count += int(new_count.item())
            self._mean_abs.copy_(merged.to(self._mean_abs.dtype))
        self._reset_new_stats()

    def normalize(self, x: torch.Tensor) -> torch.Tensor:
        """x / max(mean |x|, min_diff) clipped to ±clip; x [..., *shape]."""
        norm = x / self._mean_abs.clamp_min(self._min_diff)
        if math.isfinite(self._clip):
            norm = norm.clamp(-self._clip, self._clip)
        return norm.to(self._mean_abs.dtype)

    def unnormalize(self, norm_x: torch.Tensor) -> torch.Tensor:
        return (norm_x * self._mean_abs.clamp_min(self._min_diff)).to(self._mean_abs.dtype)

    def get_shape(self) -> tuple[int, ...]:
        return self._shape

    def get_count(self) -> int:
        return int(self._count.item())

    def get_mean_abs(self) -> torch.Tensor:
        return self._mean_abs

    def _reset_new_stats(self) -> None:
        device = self._mean_abs.device
        self._new_count = torch.zeros((), dtype=torch.float64, device=device)
        self._new_sum_abs = torch.zeros(self._shape, dtype=torch.float64, device=device)
