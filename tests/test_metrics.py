"""Gap statistics: SSIM reference values, gap_closed, bootstrap coverage."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from handradar.metrics import (
    bootstrap_difference,
    bootstrap_gap_closed,
    gap_closed,
    per_example_mse,
    per_example_ssim,
)


def test_ssim_identical_is_one_and_noise_lowers_it():
    rng = np.random.default_rng(0)
    x = torch.as_tensor(rng.uniform(0, 1, (5, 64, 32)), dtype=torch.float32)
    np.testing.assert_allclose(per_example_ssim(x, x), 1.0, atol=1e-6)
    noisy = (x + 0.3 * torch.randn_like(x)).clamp(0, 1)
    s = per_example_ssim(x, noisy)
    assert s.shape == (5,) and np.all(s < 0.9)


def test_mse_matches_numpy():
    rng = np.random.default_rng(1)
    a, b = rng.uniform(0, 1, (2, 3, 64, 32))
    np.testing.assert_allclose(per_example_mse(torch.tensor(a), torch.tensor(b)), ((a - b) ** 2).mean(axis=(1, 2)),
                               rtol=1e-5)


def test_gap_closed_definition():
    before = np.array([0.6, 0.6])  # gap 0.4
    after = np.array([0.7, 0.7])  # gap 0.3
    assert gap_closed(before, after) == pytest.approx(0.25)
    assert gap_closed(before, before) == 0.0


def test_bootstrap_interval_covers_true_effect_and_excludes_zero():
    rng = np.random.default_rng(2)
    base = rng.uniform(0.4, 0.8, 200)
    after = base + 0.05 + rng.normal(0, 0.01, 200)
    b = bootstrap_gap_closed(base, after, seed=3)
    assert b.ci95[0] < b.estimate < b.ci95[1]
    assert b.significant
    null = bootstrap_gap_closed(base, base + rng.normal(0, 0.01, 200), seed=3)
    assert null.ci95[0] < 0 < null.ci95[1]


def test_bootstrap_difference_separates_clear_winner_from_tie():
    rng = np.random.default_rng(4)
    base = rng.uniform(0.4, 0.8, 150)
    strong = base + 0.08 + rng.normal(0, 0.01, 150)
    weak = base + 0.02 + rng.normal(0, 0.01, 150)
    _, ci = bootstrap_difference(base, strong, weak)
    assert ci[0] > 0
    twin = strong + rng.normal(0, 0.01, 150)
    _, ci_tie = bootstrap_difference(base, strong, twin)
    assert ci_tie[0] < 0 < ci_tie[1]


def test_speckle_deviance_closed_forms():
    """0 for proportional powers at any scale; Euler's gamma for exponential speckle around the
    expectation; lopsided: missing power costs more than the same excess."""
    from handradar.metrics import speckle_deviance

    range_db = 60.0
    to_unit = lambda p: 1.0 + 10.0 * np.log10(p) / range_db  # power relative to the peak -> [0, 1]
    rng = np.random.default_rng(0)
    expectation = np.exp(rng.uniform(np.log(1e-2), 0.0, size=(8, 64, 128)))  # within 20 dB of the peak
    sim = to_unit(expectation)
    # proportional: the same powers scaled by 1/3 (shown against another peak) give deviance 0
    assert np.allclose(speckle_deviance(to_unit(expectation / 3.0), sim, range_db), 0.0, atol=1e-9)
    # exponential speckle around the expectation: E[log E] = -gamma, E[E] = 1, so gamma per row
    measured = expectation * rng.exponential(size=expectation.shape)
    measured = measured / measured.max(axis=(1, 2), keepdims=True)
    floor = 10 ** (-range_db / 10.0)  # the display floor's power
    assert (measured > floor).mean() > 0.999  # the closed form needs (nearly) every pixel above it
    d = speckle_deviance(to_unit(np.maximum(measured, floor)), sim, range_db)
    assert np.allclose(d, np.euler_gamma, atol=0.05)  # 3.5 sd of a row's mean log over 8192 pixels
    # asymmetric: a bright pixel the simulation lacks (10 dB above it) costs more than 10 dB too much
    base = np.full((1, 8, 8), 0.5)
    missing, excess = base.copy(), base.copy()
    missing[0, 0, 0] += 10.0 / range_db
    excess[0, 0, 0] -= 10.0 / range_db
    assert speckle_deviance(missing, base, range_db)[0] > 2 * speckle_deviance(excess, base, range_db)[0] > 0
