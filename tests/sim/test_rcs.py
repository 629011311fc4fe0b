"""RCS functions against their closed forms, the broadside cap, and gradcheck."""

from __future__ import annotations

import math

import numpy as np
import torch

from handradar.sim.rcs import cos_angle, cylinder_rcs_m2, disc_rcs_m2

LAM = 3.85e-3


def test_cylinder_rcs_closed_form_off_broadside():
    r, length = 0.009, 0.04
    for deg in (5.0, 30.0, 60.0, 85.0):
        th = math.radians(deg)
        expected = LAM * r * math.sin(th) / (8 * math.pi * math.cos(th) ** 2)
        got = float(cylinder_rcs_m2(torch.tensor(math.cos(th), dtype=torch.float64), r, length, LAM))
        assert math.isclose(got, expected, rel_tol=1e-12)


def test_cylinder_rcs_is_capped_by_the_broadside_value():
    r, length = 0.009, 0.04
    cap = 2 * math.pi * r * length**2 / LAM
    cos = torch.tensor([0.0, 1e-5, -1e-5, 1e-3], dtype=torch.float64)
    got = cylinder_rcs_m2(cos, r, length, LAM)
    assert torch.allclose(got[:3], torch.full((3,), cap, dtype=torch.float64))
    # the cap takes over exactly where the formula exceeds it: min(formula, cap) everywhere
    c = torch.linspace(-1, 1, 2001, dtype=torch.float64)
    sin = torch.sqrt(1 - c**2)
    formula = LAM * r * sin / (8 * math.pi * c**2)
    torch.testing.assert_close(cylinder_rcs_m2(c, r, length, LAM)[1:-1], torch.minimum(formula, torch.tensor(cap, dtype=torch.float64))[1:-1])
    assert float(cylinder_rcs_m2(torch.tensor(1.0), r, length, LAM)) < 1e-6  # end-on: (almost) nothing


def test_disc_rcs_peak_and_lobe():
    a = 0.02
    peak = 4 * math.pi * (math.pi * a**2) ** 2 / LAM**2
    assert math.isclose(float(disc_rcs_m2(torch.tensor(1.0, dtype=torch.float64), a, LAM)), peak, rel_tol=1e-12)
    th = math.radians(3.0)
    x = 2 * math.pi / LAM * a * math.sin(th)
    got = float(disc_rcs_m2(torch.tensor(math.cos(th), dtype=torch.float64), a, LAM))
    assert math.isclose(got, peak * math.cos(th) ** 2 * math.exp(-x**2 / 4), rel_tol=1e-12)


def test_cos_angle():
    a = torch.tensor([[1.0, 0, 0], [0, 2, 0], [0, 0, 0]], dtype=torch.float64)
    b = torch.tensor([[3.0, 0, 0], [1, 1, 0], [1, 0, 0]], dtype=torch.float64)
    np.testing.assert_allclose(cos_angle(a, b).numpy(), [1.0, 1 / math.sqrt(2), 0.0])


def test_gradcheck():
    c = torch.tensor([0.2, -0.5, 0.9, 1e-4], dtype=torch.float64, requires_grad=True)
    r = torch.tensor(0.009, dtype=torch.float64, requires_grad=True)
    length = torch.tensor(0.04, dtype=torch.float64, requires_grad=True)
    torch.autograd.gradcheck(lambda c, r, l: cylinder_rcs_m2(c, r, l, LAM), (c, r, length))
    a = torch.tensor(0.015, dtype=torch.float64, requires_grad=True)
    torch.autograd.gradcheck(lambda c, a: disc_rcs_m2(c, a, LAM), (c, a))
    u = torch.randn(4, 3, dtype=torch.float64, requires_grad=True)
    v = torch.randn(4, 3, dtype=torch.float64, requires_grad=True)
    torch.autograd.gradcheck(cos_angle, (u, v))
    # no NaN gradient at broadside (the capped branch)
    c0 = torch.tensor([0.0], dtype=torch.float64, requires_grad=True)
    cylinder_rcs_m2(c0, 0.009, 0.04, LAM).sum().backward()
    assert torch.isfinite(c0.grad).all()


def test_aspect_exponent_compresses_toward_the_cap():
    r, length = 0.009, 0.04
    cap = 2 * math.pi * r * length**2 / LAM
    c = torch.linspace(-0.99, 0.99, 199, dtype=torch.float64)
    paper = cylinder_rcs_m2(c, r, length, LAM)
    torch.testing.assert_close(cylinder_rcs_m2(c, r, length, LAM, exponent=1.0), paper)
    half = cylinder_rcs_m2(c, r, length, LAM, exponent=0.5)
    torch.testing.assert_close(half, torch.sqrt(paper * cap))  # cap (sigma / cap)^0.5, in closed form
    assert bool((half >= paper).all()) and bool((half <= cap * (1 + 1e-12)).all())
    torch.testing.assert_close(cylinder_rcs_m2(c, r, length, LAM, exponent=0.0), torch.full_like(c, cap))
    # a zero-length bone reflects nothing at any exponent (no 0/0)
    zero = cylinder_rcs_m2(torch.tensor([0.3, 0.0], dtype=torch.float64), r, 0.0, LAM, exponent=0.5)
    assert torch.equal(zero, torch.zeros(2, dtype=torch.float64))
    cc = torch.tensor([0.2, -0.5, 0.9], dtype=torch.float64, requires_grad=True)
    rr = torch.tensor(0.009, dtype=torch.float64, requires_grad=True)
    torch.autograd.gradcheck(lambda c, r: cylinder_rcs_m2(c, r, length, LAM, exponent=0.5), (cc, rr))
