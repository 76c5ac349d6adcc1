"""The divergence guard's check: the first non-finite quantity, by name and kind, and no false alarm."""

from __future__ import annotations

import pytest
import torch

from mimickit.learning.divergence import first_non_finite, gradient_norm


def test_all_finite_is_none_even_when_a_sum_would_overflow() -> None:
    huge = torch.full((8,), 3e38)  # its float32 sum is inf; every element is finite
    assert first_non_finite([("observation", huge), ("critic loss", 1.5), ("count", torch.arange(3))]) is None


@pytest.mark.parametrize(("value", "kind"), [(float("nan"), "nan"), (float("inf"), "inf"), (float("-inf"), "-inf")])
def test_the_first_non_finite_quantity_is_named_with_its_kind(value: float, kind: str) -> None:
    obs = torch.zeros(4, 3)
    obs[2, 1] = value
    quantities = [("action", torch.ones(2)), ("observation", obs), ("critic loss", float("nan"))]
    assert first_non_finite(quantities) == f"observation is {kind}"
    assert first_non_finite([("action", torch.ones(2)), ("critic loss", value)]) == f"critic loss is {kind}"


def test_gradient_norm_of_parameters_with_gradients() -> None:
    a, b = torch.nn.Parameter(torch.zeros(2)), torch.nn.Parameter(torch.zeros(3))
    assert gradient_norm([a, b]) is None
    a.grad = torch.tensor([3.0, 4.0])
    assert float(gradient_norm([a, b])) == 5.0
    b.grad = torch.tensor([0.0, float("inf"), 0.0])
    assert first_non_finite([("gradient norm", gradient_norm([a, b]))]) == "gradient norm is inf"
