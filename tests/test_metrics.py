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


def test_per_example_ssim_in_chunks_is_the_same():
    rng = np.random.default_rng(0)
    a, b = rng.uniform(size=(7, 16, 16)), rng.uniform(size=(7, 16, 16))
    np.testing.assert_array_equal(per_example_ssim(a, b, chunk=3), per_example_ssim(a, b))
    assert per_example_ssim(a[:0], b[:0]).shape == (0,)
