"""Exponential moving average of a model's weights, as the reference's `tinymdm/EMA.py`.

`update()` is called after every optimiser step. Every `update_every` calls the copy moves towards the
model (`ema = decay·ema + (1 − decay)·model`, parameters only); until call `update_after_step` it is
set equal to the model instead. The module holds the model (`model`), the copy (`ema_model`) and the call
counter (`step`), the reference's state-dict keys; calling it runs the copy.
"""

from __future__ import annotations

import copy

import torch
from torch import nn


class EMA(nn.Module):
    step: torch.Tensor

    def __init__(self, model: nn.Module, beta: float, update_every: int, update_after_step: int) -> None:
        super().__init__()
        self.model = model
        self.ema_model = copy.deepcopy(model)
        for p in self.ema_model.parameters():
            p.requires_grad_(False)
        self.decay = beta
        self.update_every = update_every
        self.update_after_step = update_after_step
        self.register_buffer("step", torch.tensor(0))

    @torch.no_grad()
    def update(self) -> None:
        step = int(self.step.item())
        self.step += 1
        if step % self.update_every != 0:
            return
        if step <= self.update_after_step:
            self.ema_model.load_state_dict(self.model.state_dict())
            return
        for ema_p, p in zip(self.ema_model.parameters(), self.model.parameters(), strict=True):
            ema_p.mul_(self.decay).add_(p.detach(), alpha=1.0 - self.decay)

    def forward(self, *args: object, **kwargs: object) -> torch.Tensor:
        return self.ema_model(*args, **kwargs)
