"""The divergence guard: the first non-finite quantity of a training iteration.

The agent lists an iteration's quantities in the order they arise (observations, actions and rewards
of the rollout, the advantage statistics, the losses, the gradient norm, the weights), so the reason
names where the NaN or infinity entered, not where it spread to: `critic loss is nan`.
All finite (the usual case) costs one sum per tensor and one device→host transfer for all together.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import torch

Quantity = tuple[str, "torch.Tensor | float"]


def non_finite_kind(value: torch.Tensor | float) -> str | None:
    """The kind ("nan", "inf", "-inf") of a value (or a tensor holding one) that is not finite, else None."""
    if isinstance(value, torch.Tensor):
        if not value.is_floating_point():
            return None
        if bool(value.isnan().any()):
            return "nan"
        if bool(value.isposinf().any()):
            return "inf"
        return "-inf" if bool(value.isneginf().any()) else None
    v = float(value)
    if math.isnan(v):
        return "nan"
    return None if math.isfinite(v) else ("inf" if v > 0 else "-inf")


def first_non_finite(quantities: Iterable[Quantity]) -> str | None:
    """`"<name> is nan"` for the first quantity that is not finite, or None when all are."""
    items = list(quantities)
    tensors = [v for _, v in items if isinstance(v, torch.Tensor) and v.is_floating_point() and v.numel()]
    floats_ok = all(math.isfinite(float(v)) for _, v in items if not isinstance(v, torch.Tensor))
    # A tensor's sum is NaN/inf when an element is (and, rarely, when finite elements overflow it: the
    # exact per-element check below then finds nothing). Several times cheaper than isfinite().all().
    tensors_ok = not tensors or bool(torch.stack([t.sum().isfinite().to(tensors[0].device) for t in tensors]).all())
    if floats_ok and tensors_ok:
        return None
    for name, value in items:
        kind = non_finite_kind(value)
        if kind is not None:
            return f"{name} is {kind}"
    return None


def gradient_norm(params: Iterable[torch.nn.Parameter]) -> torch.Tensor | None:
    """The global L2 norm of the parameters' current gradients (None when none has one)."""
    norms = [torch.linalg.vector_norm(p.grad.detach()) for p in params if p.grad is not None]
    return torch.linalg.vector_norm(torch.stack(norms)) if norms else None
