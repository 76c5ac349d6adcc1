import numpy as np
import pytest
import torch

from mimickit.learning.normalizer import DiffNormalizer, Normalizer


def test_running_mean_std_matches_numpy_over_several_updates():
    rng = np.random.default_rng(0)
    batches = [rng.normal(loc=[1.0, -3.0, 10.0], scale=[0.5, 2.0, 4.0], size=(n, 3)) for n in (7, 50, 13)]
    norm = Normalizer((3,))
    for b in batches:
        # leading dims are all samples: record [T, N, 3] blocks
        norm.record(torch.tensor(b, dtype=torch.float32).reshape(-1, 1, 3))
        norm.update()
    data = np.concatenate(batches)
    np.testing.assert_allclose(norm.get_mean().numpy(), data.mean(0), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(norm.get_std().numpy(), data.std(0), rtol=1e-4)
    assert norm.get_count() == len(data)


def test_record_without_update_changes_nothing_and_empty_update_is_a_noop():
    norm = Normalizer((2,))
    norm.record(torch.ones(4, 2) * 5)
    assert torch.equal(norm.get_mean(), torch.zeros(2))
    norm.update()
    norm.update()  # nothing new recorded
    assert torch.allclose(norm.get_mean(), torch.full((2,), 5.0))


def test_min_std_clip_and_unnormalize():
    norm = Normalizer((2,), min_std=1e-4, clip=10.0)
    norm.record(torch.tensor([[1.0, 0.0], [1.0, 2.0]]))
    norm.update()
    assert norm.get_std()[0].item() == pytest.approx(1e-4)  # constant dimension: std floored
    x = torch.tensor([[2.0, 3.0]])
    z = norm.normalize(x)
    assert z[0, 0].item() == 10.0  # (2 - 1) / 1e-4 clipped to 10
    assert z[0, 1].item() == pytest.approx(2.0)
    assert torch.allclose(norm.unnormalize(torch.tensor([[0.5, 2.0]])), torch.tensor([[1.00005, 3.0]]))


def test_state_dict_keys_and_dtypes_match_the_reference():
    norm = Normalizer((5,), init_mean=torch.full((5,), 2.0), init_std=torch.full((5,), 3.0))
    sd = norm.state_dict()
    assert list(sd) == ["_count", "_mean", "_std"]
    assert sd["_count"].dtype == torch.long and sd["_count"].shape == (1,)
    assert sd["_mean"].shape == (5,) and sd["_std"].shape == (5,)
    assert not any(p.requires_grad for p in norm.parameters())


def test_diff_normalizer_scales_by_the_running_mean_abs_without_centring():
    norm = DiffNormalizer((2,))
    x = torch.tensor([[2.0, -8.0], [-4.0, 0.0]])
    torch.testing.assert_close(norm.normalize(x), x)  # mean |x| starts at 1: raw differences
    norm.record(x.view(2, 1, 2))  # leading dims are samples
    norm.update()  # mean |x| = (3, 4)
    torch.testing.assert_close(norm.get_mean_abs(), torch.tensor([3.0, 4.0]))
    torch.testing.assert_close(norm.normalize(x), torch.tensor([[2 / 3, -2.0], [-4 / 3, 0.0]]))
    assert torch.equal(norm.normalize(torch.zeros(2)), torch.zeros(2)), "zero stays zero (no mean shift)"
    norm.record(torch.tensor([[6.0, 0.0]]))  # merged by counts: (2·3 + 6) / 3, (2·4 + 0) / 3
    norm.update()
    torch.testing.assert_close(norm.get_mean_abs(), torch.tensor([4.0, 8 / 3]))
    assert norm.get_count() == 3
    assert set(norm.state_dict()) == {"_count", "_mean_abs"}


def test_diff_normalizer_floor_and_clip():
    norm = DiffNormalizer((2,), clip=5.0)
    norm.record(torch.tensor([[1e-6, 1.0]]))
    norm.update()
    # mean |x| 1e-6 is floored at 1e-4: 1e-3 / 1e-4 = 10, clipped to 5.
    torch.testing.assert_close(norm.normalize(torch.tensor([1e-3, -7.0])), torch.tensor([5.0, -5.0]))
