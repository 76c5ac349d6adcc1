"""An optimiser that keeps the parameters of all processes identical, as the reference's.

`step(loss)`: zero grad → backward → (multi-process) average the gradients over processes → optional
global-norm clip → optimiser step → every `CHECK_SYNC_STEPS` steps (from step 0) assert that every
process still holds rank 0's parameters. Parameters are broadcast from rank 0 on construction and on
`sync()`, so all processes start from the same network whatever their seeds.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import torch

from mimickit.learning import mp_util
from mimickit.learning.agent_config import OptimizerConfig
from mimickit.util.warn import warn


class MPOptimizer:
    CHECK_SYNC_STEPS = 1000

    def __init__(self, config: OptimizerConfig, params: Iterable[torch.nn.Parameter]) -> None:
        self._params = [p for p in params if p.requires_grad]
        self._grad_clip = config.grad_clip
        self._optimizer = _build_torch_optimizer(config, self._params)
        self._steps = 0
        if config.use_amp:
            warn("use_amp (mixed precision) is not supported; training in float32", stacklevel=2)
        self.sync()

    def step(self, loss: torch.Tensor) -> None:
        """One update from the scalar `loss` (already averaged over this process's minibatch)."""
        # Backward then writes each gradient instead of adding it to zeros (a fill and an add per tensor
        # saved; the same values). A parameter this loss does not reach gets zeros where it had a gradient
        # before (and with several processes, whose all-reduce needs every one), as zero_grad left it.
        had_grad = [p.grad is not None or mp_util.enable_mp() for p in self._params]
        self._optimizer.zero_grad(set_to_none=True)
        loss.backward()
        for p, had in zip(self._params, had_grad, strict=True):
            if p.grad is None and had:
                p.grad = torch.zeros_like(p)
        if mp_util.enable_mp():
            self._average_grads()
        if self._grad_clip > 0.0:
            torch.nn.utils.clip_grad_norm_(self._params, self._grad_clip)
        self._optimizer.step()
        if mp_util.enable_mp() and self._steps % self.CHECK_SYNC_STEPS == 0:
            assert self._check_synced(), "network parameters are no longer identical across processes"
        self._steps += 1

    def sync(self) -> None:
        """Copy rank 0's parameters to every process."""
        if not mp_util.enable_mp():
            return
        with torch.no_grad():
            for p in self._params:
                p.copy_(mp_util.broadcast(p))

    def get_steps(self) -> int:
        return self._steps

    def state_dict(self) -> dict[str, Any]:
        return {"optimizer": self._optimizer.state_dict(), "steps": self._steps}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore the optimiser's running state (momenta, step counts). Its hyperparameters (learning
        rate, weight decay, ...) stay this config's: torch would take the checkpoint's, so a run resumed
        with a new agent config (a lower learning rate after a divergence) would silently train with the old."""
        configured = [{k: v for k, v in group.items() if k != "params"} for group in self._optimizer.param_groups]
        self._optimizer.load_state_dict(state["optimizer"])
        for group, hyper in zip(self._optimizer.param_groups, configured, strict=True):
            group.update(hyper)
        self._steps = int(state.get("steps", 0))

    def _average_grads(self) -> None:
        """All-reduce every gradient as one flat vector and divide by the number of processes."""
        flat = torch.cat([p.grad.reshape(-1) for p in self._params])
        mp_util.reduce_inplace_mean(flat)
        offset = 0
        for p in self._params:
            n = p.numel()
            p.grad.copy_(flat[offset : offset + n].view_as(p))
            offset += n

    def _check_synced(self) -> bool:
        synced = all(torch.equal(p, mp_util.broadcast(p)) for p in self._params)
        flag = torch.tensor([int(synced)], dtype=torch.int64, device=self._params[0].device)
        mp_util.reduce_inplace_min(flag)
        return bool(flag.item())


def _build_torch_optimizer(config: OptimizerConfig, params: list[torch.nn.Parameter]) -> torch.optim.Optimizer:
    # foreach: one multi-tensor kernel per update term instead of a Python loop over the parameters; on the
    # CPU the same weights bit for bit (`fused` is faster on GPUs but rounds differently).
    if config.type == "SGD":
        return torch.optim.SGD(
            params, lr=config.learning_rate, momentum=0.9, weight_decay=config.weight_decay, foreach=True
        )
    # "Adam" is AdamW with the yaml's weight decay (default 0), PyTorch's default betas and eps.
    return torch.optim.AdamW(params, lr=config.learning_rate, weight_decay=config.weight_decay, foreach=True)
