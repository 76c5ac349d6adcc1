"""Rollout storage: named arrays [length, batch, ...] filled one env step (row) at a time, as the reference's.

Arrays are created on the first `record(name, x)`; `inc()` advances the row (wrapping) and counts
`batch` samples. Flat views [length·batch, ...] share memory with the arrays. `sample(n)` walks a
random permutation of the flat indices (a new permutation when it runs out), so `k` calls of
`sample(length·batch / k)` visit every sample once: one epoch.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping

import torch


class Minibatch(Mapping[str, torch.Tensor]):
    """Rows `idx` of named flat arrays. A loss reads a few of the buffer's arrays (PPO's actor: 5 of 9),
    so each is gathered on first read: gathering all of them was 10% of an actor update."""

    def __init__(self, flat: dict[str, torch.Tensor], idx: torch.Tensor) -> None:
        self._flat = flat
        self._idx = idx
        self._rows: dict[str, torch.Tensor] = {}

    def __getitem__(self, name: str) -> torch.Tensor:
        if name not in self._rows:
            self._rows[name] = self._flat[name][self._idx]
        return self._rows[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._flat)

    def __len__(self) -> int:
        return len(self._flat)


class ExperienceBuffer:
    def __init__(self, buffer_length: int, batch_size: int, device: torch.device | str) -> None:
        self._length = buffer_length
        self._batch = batch_size
        self._device = torch.device(device)
        self._buffers: dict[str, torch.Tensor] = {}
        self._flat: dict[str, torch.Tensor] = {}
        self._head = 0
        self._total_samples = 0
        self._perm = torch.randperm(self.capacity, device=self._device)
        self._perm_pos = 0

    @property
    def capacity(self) -> int:
        return self._length * self._batch

    def record(self, name: str, data: torch.Tensor) -> None:
        """Copy `data` [batch, ...] into row `head` of array `name` (created on first use)."""
        if name not in self._buffers:
            self._add(name, torch.zeros((self._length, *data.shape), dtype=data.dtype, device=self._device))
        self._buffers[name][self._head].copy_(data)

    def inc(self) -> None:
        """Advance to the next row (wrapping around) and count one row of samples."""
        self._head = (self._head + 1) % self._length
        self._total_samples += self._batch

    def reset(self) -> None:
        """Start filling from row 0 again; the total sample count is kept."""
        self._head = 0

    def clear(self) -> None:
        self.reset()
        self._total_samples = 0

    def get_total_samples(self) -> int:
        """Samples recorded since construction or `clear()` (this process only)."""
        return self._total_samples

    def get_sample_count(self) -> int:
        """Valid samples currently held: min(total, capacity)."""
        return min(self._total_samples, self.capacity)

    def has(self, name: str) -> bool:
        return name in self._buffers

    def get_data(self, name: str) -> torch.Tensor:
        """Array `name` [length, batch, ...]."""
        return self._buffers[name]

    def get_data_flat(self, name: str) -> torch.Tensor:
        """Array `name` viewed as [length·batch, ...] (row-major: sample i = row i // batch)."""
        return self._flat[name]

    def set_data(self, name: str, data: torch.Tensor) -> None:
        """Store a derived array [length, batch, ...] (e.g. targets, advantages)."""
        if name not in self._buffers:
            self._add(name, torch.zeros_like(data, device=self._device))
        self._buffers[name].copy_(data)

    def set_data_flat(self, name: str, data: torch.Tensor) -> None:
        """Store a derived array given flat [length·batch, ...]."""
        self.set_data(name, data.reshape(self._length, self._batch, *data.shape[1:]))

    def sample(self, n: int) -> Minibatch:
        """`n` samples of every array, as flat tensors [n, ...] (each gathered when first read)."""
        idx = self._next_indices(n) % max(self.get_sample_count(), 1)
        return Minibatch(self._flat, idx)

    def push(self, data: dict[str, torch.Tensor]) -> None:
        """Append `n` rows [n, batch, ...] of every named array, ring-style (replay buffers)."""
        n = next(iter(data.values())).shape[0]
        if n > self._length:  # only the newest rows fit
            data = {name: x[-self._length :] for name, x in data.items()}
            n = self._length
        for name, x in data.items():
            if name not in self._buffers:
                self._add(name, torch.zeros((self._length, *x.shape[1:]), dtype=x.dtype, device=self._device))
        rows = (self._head + torch.arange(n, device=self._device)) % self._length
        for name, x in data.items():
            self._buffers[name][rows] = x.to(self._device)
        self._head = (self._head + n) % self._length
        self._total_samples += n * self._batch

    def _add(self, name: str, array: torch.Tensor) -> None:
        self._buffers[name] = array
        self._flat[name] = array.view(self.capacity, *array.shape[2:])

    def _next_indices(self, n: int) -> torch.Tensor:
        parts = []
        while n > 0:
            if self._perm_pos >= self.capacity:
                self._perm = torch.randperm(self.capacity, device=self._device)
                self._perm_pos = 0
            take = min(n, self.capacity - self._perm_pos)
            parts.append(self._perm[self._perm_pos : self._perm_pos + take])
            self._perm_pos += take
            n -= take
        return torch.cat(parts)
