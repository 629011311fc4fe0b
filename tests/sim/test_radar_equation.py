"""sim.scatterers.radar_amplitude against the radar equation built up from first principles (power
density at the target, power it reradiates, the receive antenna's effective aperture)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from handradar.sim.scatterers import radar_amplitude

WAVELENGTH_M = 3.9e-3  # 77 GHz


def received_power_w(p_t: float, g_t_dbi: float, g_r_dbi: float, sigma_m2, r_tx_m, r_rx_m, lam: float):
    """Bistatic radar equation, step by step (Skolnik, Introduction to Radar Systems, ch. 2)."""
    g_t, g_r = 10.0 ** (g_t_dbi / 10.0), 10.0 ** (g_r_dbi / 10.0)
    density_at_target = p_t * g_t / (4.0 * np.pi * r_tx_m**2)  # W/m^2
    reradiated = density_at_target * sigma_m2  # W, isotropically by the definition of the RCS
    density_at_radar = reradiated / (4.0 * np.pi * r_rx_m**2)  # W/m^2
    aperture = g_r * lam**2 / (4.0 * np.pi)  # m^2, effective area of the receive antenna
    return density_at_radar * aperture


def test_amplitude_is_the_square_root_of_the_received_power():
    rng = np.random.default_rng(0)
    sigma = rng.uniform(1e-6, 1e-2, 50)
    r_tx, r_rx = rng.uniform(0.1, 1.0, 50), rng.uniform(0.1, 1.0, 50)
    for p_t, g_t, g_r in ((0.0158, 10.5, 10.5), (1.0, 0.0, 0.0), (0.2, 3.0, 12.0)):
        a = radar_amplitude(torch.as_tensor(sigma), torch.as_tensor(r_tx), torch.as_tensor(r_rx), WAVELENGTH_M,
                            p_t, g_t, g_r).numpy()
        np.testing.assert_allclose(a**2, received_power_w(p_t, g_t, g_r, sigma, r_tx, r_rx, WAVELENGTH_M), rtol=1e-9)


def test_scaling_laws_of_a_direct_path():
    """Monostatic (R_tx = R_rx = R): power ~ R^-4 (amplitude ~ R^-2), ~ sigma, ~ lambda^2, ~ P_t G_t G_r."""
    amp = lambda sigma=1e-4, r=0.3, lam=WAVELENGTH_M, p=0.0158, g=10.5: float(radar_amplitude(
        torch.tensor([sigma], dtype=torch.float64), torch.tensor([r], dtype=torch.float64),
        torch.tensor([r], dtype=torch.float64), lam, p, g, g)[0])
    assert amp(r=0.6) / amp(r=0.3) == pytest.approx(0.25, rel=1e-12)
    assert amp(sigma=4e-4) / amp(sigma=1e-4) == pytest.approx(2.0, rel=1e-9)
    assert amp(lam=2 * WAVELENGTH_M) / amp() == pytest.approx(2.0, rel=1e-12)
    assert amp(p=4 * 0.0158) / amp() == pytest.approx(2.0, rel=1e-12)
    assert amp(g=20.5) / amp() == pytest.approx(10.0, rel=1e-12)  # +10 dB on each antenna: +20 dB of power
    # the closed form at one point: sqrt(P G^2 lambda^2 sigma / ((4 pi)^3 R^4)), G = 10^1.05
    g = 10.0**1.05
    assert amp() == pytest.approx(math.sqrt(0.0158 * g * g * WAVELENGTH_M**2 * 1e-4 / ((4 * math.pi) ** 3 * 0.3**4)),
                                  rel=1e-9)
    assert amp(sigma=0.0) < 1e-9 * amp()  # no RCS, no return
