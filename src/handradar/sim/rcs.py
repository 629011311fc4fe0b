"""Radar cross sections (m^2) of the simulator's reflectors: pure, differentiable torch functions.

Cylinder (Tang et al., after Knott's finite-cylinder formulas): with theta the angle between the
line of sight and the cylinder axis,

    sigma(theta) = lambda r sin(theta) / (8 pi cos^2(theta)),

which diverges at broadside (theta = 90 deg); there it is capped by the broadside value

    sigma_broadside = 2 pi r L^2 / lambda,

i.e. sigma = min(formula, cap). Only |cos theta| enters, so the sign of the axis is irrelevant.

Aspect exponent e (``exponent``, 1 = the formula above): sigma_e = cap (sigma / cap)^e compresses
the 30-40 dB between a bone seen end-on and at broadside toward the broadside value (e = 0: every
aspect returns the cap). An ideal smooth cylinder is the most specular a finger can be; a tapered,
jointed, skin-covered one returns more off broadside. The gap diagnosis fits e on its calibration
split as a generic calibration of the baseline (handradar.gap.diagnosis).

Flat disc (the palm effect): physical-optics disc of radius a, angle theta between the line of
sight and the disc normal,

    sigma(theta) = (4 pi A^2 / lambda^2) cos^2(theta) [2 J1(x) / x]^2,   A = pi a^2, x = k a sin(theta),

with the Airy factor replaced by its main-lobe Gaussian exp(-x^2 / 4) (equal to second order in x;
a palm is curved, so the side lobes of a flat disc are not physical, and torch has no J1 gradient).

Public API (broadcasting tensors; metres, m^2):

    cos_angle(a (..., 3), b (..., 3)) -> (...) cosine of the angle between two vectors (0 for zero vectors)
    cylinder_rcs_m2(cos_theta, radius_m, length_m, wavelength_m, exponent=1.0) -> sigma (...)
    disc_rcs_m2(cos_theta, radius_m, wavelength_m) -> sigma (...)
"""

from __future__ import annotations

import math

import torch


def cos_angle(a: torch.Tensor, b: torch.Tensor, eps: float = 1e-12) -> torch.Tensor:
    """Cosine of the angle between vectors a and b (..., 3); 0 where either has zero length."""
    dot = (a * b).sum(-1)
    na2, nb2 = (a * a).sum(-1), (b * b).sum(-1)
    ok = (na2 > eps) & (nb2 > eps)
    denom = torch.sqrt(torch.where(ok, na2 * nb2, torch.ones_like(na2)))
    return torch.where(ok, dot / denom, torch.zeros_like(dot))


def cylinder_rcs_m2(cos_theta: torch.Tensor, radius_m: torch.Tensor | float, length_m: torch.Tensor | float,
                    wavelength_m: float, exponent: float = 1.0) -> torch.Tensor:
    """Finite-cylinder RCS, min(lambda r sin / (8 pi cos^2), 2 pi r L^2 / lambda), m^2; with an aspect
    ``exponent`` e != 1, cap (sigma / cap)^e (module doc)."""
    cos_theta = torch.as_tensor(cos_theta)
    radius_m = torch.as_tensor(radius_m, dtype=cos_theta.dtype, device=cos_theta.device)
    length_m = torch.as_tensor(length_m, dtype=cos_theta.dtype, device=cos_theta.device)
    cos2 = (cos_theta * cos_theta).clamp(max=1.0)
    sin = torch.sqrt((1.0 - cos2).clamp_min(1e-12))
    cap = 2.0 * math.pi * radius_m * length_m**2 / wavelength_m
    numer = wavelength_m * radius_m * sin
    # the formula exceeds the cap exactly where numer >= 8 pi cos^2 cap; evaluate it only elsewhere so
    # that neither branch divides by cos^2 = 0 (no inf * 0 = nan in the backward pass)
    capped = numer >= 8.0 * math.pi * cos2 * cap
    safe_cos2 = torch.where(capped, torch.ones_like(cos2), cos2)
    formula = numer / (8.0 * math.pi * safe_cos2)
    sigma = torch.where(capped, cap, formula)
    if exponent == 1.0:
        return sigma
    # sigma / cap is in (0, 1] wherever the cap is positive; a zero-length bone (cap 0) stays at 0
    safe_cap = torch.where(cap > 0, cap, torch.ones_like(cap))
    return torch.where(cap > 0, safe_cap * (sigma / safe_cap).clamp_min(1e-30) ** exponent, torch.zeros_like(sigma))


def disc_rcs_m2(cos_theta: torch.Tensor, radius_m: torch.Tensor | float, wavelength_m: float) -> torch.Tensor:
    """Physical-optics disc RCS with a Gaussian main lobe (see module doc), m^2."""
    cos_theta = torch.as_tensor(cos_theta)
    radius_m = torch.as_tensor(radius_m, dtype=cos_theta.dtype, device=cos_theta.device)
    cos2 = (cos_theta * cos_theta).clamp(max=1.0)
    area = math.pi * radius_m**2
    x2 = (2.0 * math.pi / wavelength_m * radius_m) ** 2 * (1.0 - cos2)
    return 4.0 * math.pi * area**2 / wavelength_m**2 * cos2 * torch.exp(-x2 / 4.0)
