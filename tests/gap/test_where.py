"""Where the gap lies: residual profiles locate a known missing component; factor breakdown."""

from __future__ import annotations

import numpy as np

from handradar.gap.where import by_factor, residual_profiles, signature_correlation


def test_residual_profile_locates_missing_doppler_band_and_time():
    rng = np.random.default_rng(0)
    sim = rng.uniform(0, 0.2, (10, 64, 32))
    measured = sim.copy()
    measured[:, 40:44, 10:20] += 0.5  # the simulator misses an approaching component at columns 10..19
    dop, time = residual_profiles(measured, sim)
    assert set(np.argsort(dop)[-4:]) == {40, 41, 42, 43}
    assert np.all(time[10:20] > 0) and np.allclose(time[:10], 0) and np.allclose(time[20:], 0)
    sim_extra = sim.copy()
    sim_extra[:, 20:22] += 0.3  # the simulator puts energy where there is none: negative residual
    dop2, _ = residual_profiles(sim, sim_extra)
    assert dop2[20] < 0 and dop2[21] < 0


def test_by_factor_groups_and_keeps_missing_factors():
    ssim = np.array([0.5, 0.7, 0.9, 0.6])
    meta = {"gesture": np.array(["grasp", "grasp", "circle", "circle"]), "occlusion": np.array([True, False, False, True]),
            "angle_deg": np.array([0.0, 30.0, -30.0, 0.0])}
    out = by_factor(ssim, meta, ("gesture", "angle_deg", "hands", "occlusion", "subject"))
    assert out["gesture"]["grasp"] == {"ssim": 0.6, "n": 2}
    assert out["occlusion"]["true"]["ssim"] == 0.55
    assert set(out["angle_deg"]) == {"0", "30", "-30"}
    assert out["hands"] == {} and out["subject"] == {}


def test_signature_correlation():
    x = np.linspace(-1, 1, 64)
    assert signature_correlation(x, 2 * x + 1) > 0.999
    assert signature_correlation(x, -x) < -0.999
    assert signature_correlation(x, np.zeros(64)) == 0.0
