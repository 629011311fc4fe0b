"""SSIM loss: reference values, shapes, gradcheck."""

from __future__ import annotations

import pytest
import torch

from handradar.metrics import ssim, ssim_loss


def test_identical_spectrograms_have_ssim_one():
    x = torch.rand(3, 64, 32)
    assert float(ssim(x, x)) == pytest.approx(1.0, abs=1e-6)
    assert float(ssim_loss(x, x)) == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("a,b", [(0.2, 0.7), (0.5, 0.5), (0.9, 0.1)])
def test_constant_images_match_the_closed_form(a, b):
    """For constant images SSIM = (2 a b + C1) / (a^2 + b^2 + C1), C1 = (0.01 * data_range)^2."""
    x = torch.full((1, 64, 32), a, dtype=torch.float64)
    y = torch.full((1, 64, 32), b, dtype=torch.float64)
    c1 = (0.01 * 1.0) ** 2
    assert float(ssim(x, y)) == pytest.approx((2 * a * b + c1) / (a * a + b * b + c1), rel=1e-9)


def test_per_example_values_and_shapes():
    x = torch.rand(4, 64, 32)
    y = x.clone()
    y[2] = torch.rand(64, 32)
    per = ssim(x, y, reduction="none")
    assert per.shape == (4,)
    assert per[[0, 1, 3]].min() > 0.999 and per[2] < 0.5
    assert float(ssim(x[:, None], y[:, None])) == pytest.approx(float(per.mean()), rel=1e-6)
    with pytest.raises(ValueError, match="spectrograms"):
        ssim(torch.rand(64, 32), torch.rand(64, 32))


def test_gradcheck():
    x = torch.rand(1, 16, 16, dtype=torch.float64, requires_grad=True)
    y = torch.rand(1, 16, 16, dtype=torch.float64)
    torch.autograd.gradcheck(lambda p: ssim_loss(p, y), (x,))


def test_fast_ssim_loss_equals_ssim_loss():
    from handradar.metrics import fast_ssim_loss

    x = torch.rand(3, 64, 32, dtype=torch.float64, requires_grad=True)
    y = torch.rand(3, 64, 32, dtype=torch.float64)
    a = ssim_loss(x, y)
    (ga,) = torch.autograd.grad(a, x)
    b = fast_ssim_loss(x, y)
    (gb,) = torch.autograd.grad(b, x)
    torch.testing.assert_close(b, a)
    torch.testing.assert_close(gb, ga)
    assert torch.backends.mkldnn.enabled  # the global flag is left as it was
    xs = torch.rand(1, 16, 16, dtype=torch.float64, requires_grad=True)
    torch.autograd.gradcheck(lambda p: fast_ssim_loss(p, y[:1, :16, :16]), (xs,))
