"""The label-keeping augmentations (handradar.models.augment), each against a direct numpy implementation with the
same parameters, and the chain's promises: the Doppler axis is never mirrored, a seed fixes the draws."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from handradar.models.augment import SpectrogramAugment, mask_band, scale_level, shift_time, stretch_time


def images(n: int = 3, d: int = 8, t: int = 12, seed: int = 0) -> torch.Tensor:
    return torch.as_tensor(np.random.default_rng(seed).random((n, 1, d, t)), dtype=torch.float32)


def test_shift_moves_whole_columns_and_lets_in_floor():
    x = images()
    shift = torch.tensor([0, 3, -5])
    out = shift_time(x, shift).numpy()
    for i, s in enumerate(shift.tolist()):
        want = np.zeros_like(x[i].numpy())
        for col in range(x.shape[-1]):  # output column col reads input column col - s
            if 0 <= col - s < x.shape[-1]:
                want[..., col] = x[i].numpy()[..., col - s]
        np.testing.assert_array_equal(out[i], want)


def test_stretch_is_linear_interpolation_about_the_centre():
    x = images(n=2, t=16)
    factor = torch.tensor([1.25, 0.8])
    out = stretch_time(x, factor).numpy()
    t = x.shape[-1]
    c = (t - 1) / 2
    for i, f in enumerate(factor.tolist()):
        src = c + (np.arange(t) - c) / f  # the input column each output column reads
        for r in range(x.shape[-2]):
            row = x[i, 0, r].numpy()
            # the row with a floor column either side, so that the last column fades to the floor over one column
            want = np.interp(src, np.arange(-1, t + 1), np.concatenate([[0.0], row, [0.0]]), left=0.0, right=0.0)
            np.testing.assert_allclose(out[i, 0, r], want, atol=1e-6)
    np.testing.assert_allclose(stretch_time(x, torch.ones(2)).numpy(), x.numpy(), atol=1e-6)  # factor 1: the image


def test_level_is_an_affine_map_clipped_to_the_range():
    x = images()
    gain, offset = torch.tensor([1.0, 1.3, 0.7]), torch.tensor([0.0, -0.1, 0.05])
    want = np.clip(gain.numpy()[:, None, None, None] * x.numpy() + offset.numpy()[:, None, None, None], 0, 1)
    np.testing.assert_allclose(scale_level(x, gain, offset).numpy(), want, atol=1e-7)


@pytest.mark.parametrize("axis", [-1, -2])
def test_mask_sets_one_band_to_the_floor(axis):
    x = images()
    start, width = torch.tensor([0, 2, 5]), torch.tensor([3, 0, 2])
    want = x.numpy().copy()
    for i in range(3):
        sl = [i, slice(None), slice(None), slice(None)]
        sl[axis] = slice(int(start[i]), int(start[i] + width[i]))
        want[tuple(sl)] = 0.0
    np.testing.assert_array_equal(mask_band(x, start, width, axis).numpy(), want)


def test_chain_never_mirrors_doppler_and_is_seeded():
    """An image with its return only on the approaching half keeps the other half at the floor, whatever is drawn
    (a level offset below 0 only; a positive one raises the whole floor, both halves alike)."""
    x = torch.zeros(16, 1, 8, 12)
    x[:, :, :4, 3:9] = torch.rand(16, 1, 4, 6) + 0.2
    aug = SpectrogramAugment(shift=4, stretch=0.2, gain=0.3, floor=0.0, time_mask=3, doppler_mask=2)
    torch.manual_seed(5)
    out = aug(x)
    assert out[:, :, 4:].abs().max() == 0 and out[:, :, :4].sum() > 0
    torch.manual_seed(5)
    assert torch.equal(aug(x), out)  # the same generator state, the same draws
    assert torch.equal(SpectrogramAugment()(x), x)  # everything off: the batch as it came
