"""Specificity evidence: per-row factors from skeletons against closed forms, the interaction test,
and a diagnosis in which an angle-dependent effect's credit comes off boresight."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from handradar.gap.diagnosis import DiagnosisConfig, diagnose
from handradar.gap.engine import RowSet
from handradar.gap.markdown import render
from handradar.gap.report import ReportError, validate_report
from handradar.gap.specificity import (
    EXPECTED_FACTOR,
    FAR_ROWS,
    far_contrast,
    far_pixels,
    interaction,
    pixel_specificity,
    row_factors,
    specificity,
)
from tests.gap.conftest import builder, gap_data

T = 11
TIMES = np.arange(T) * 0.01


def _hand(centre, normal_axis: int = 2, velocity=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(T, 21, 3): wrist and MCPs in a plane normal to ``normal_axis``, moving at ``velocity`` (m/s)."""
    e = [np.eye(3)[k] for k in range(3) if k != normal_axis]
    j = np.zeros((21, 3))
    j[0] = -0.04 * e[0]
    j[5], j[9], j[17] = 0.04 * e[0] + 0.02 * e[1], 0.045 * e[0], 0.04 * e[0] - 0.02 * e[1]
    return (j[None] + np.asarray(centre)[None, None] + TIMES[:, None, None] * np.asarray(velocity)).astype(np.float32)


def _rows(hands: list[np.ndarray], two: bool = False) -> RowSet:
    sk = np.zeros((len(hands), T, 2, 21, 3), np.float32)
    masks = np.zeros((len(hands), T, 2), bool)
    for i, h in enumerate(hands):
        sk[i, :, 0] = h
        masks[i, :, 0] = True
        if two:
            sk[i, :, 1], masks[i, :, 1] = h + np.float32(0.1), True
    return RowSet(sk, masks, TIMES)


def test_row_factors_against_closed_forms():
    f = row_factors(_rows([_hand((0, 0, 0.3)), _hand((0.3, 0, 0.3), normal_axis=0),
                           _hand((0, 0, 0.3), velocity=(0, 0, -0.5))]))
    # palm centre = mean of wrist, index, middle, pinky MCP: 0.02125 m along e0 from the given centre
    np.testing.assert_allclose(f["off_boresight_deg"][0], np.degrees(np.arctan2(0.02125, 0.3)), rtol=1e-6)
    np.testing.assert_allclose(f["off_boresight_deg"][2], np.degrees(np.arctan2(0.02125, 0.3 - 0.5 * TIMES)).mean(),
                               rtol=1e-6)
    np.testing.assert_allclose(f["off_boresight_deg"][1], 45.0, atol=0.1)  # in the plane normal to x: centre stays
    np.testing.assert_allclose(f["radial_speed_m_s"], [0.0, 0.0, 0.5], atol=2e-3)
    assert f["palm_facing"][0] > 0.99  # palm normal along z, hand on boresight
    assert abs(f["palm_facing"][1] - np.cos(np.radians(45))) < 1e-3  # normal along x, line of sight at 45 deg
    np.testing.assert_array_equal(f["two_hands"], [0, 0, 0])
    assert row_factors(_rows([_hand((0, 0, 0.3))], two=True))["two_hands"][0] == 1.0
    assert "hidden_fraction" not in f
    vis = RowSet(*(_rows([_hand((0, 0, 0.3))]).skeletons, _rows([_hand((0, 0, 0.3))]).masks, TIMES),
                 visibility=np.full((1, T, 2, 19), 0.75, np.float32))
    np.testing.assert_allclose(row_factors(vis)["hidden_fraction"], [0.25])


def test_interaction_finds_a_factor_dependent_gain_and_not_a_uniform_one():
    rng = np.random.default_rng(0)
    high = np.arange(40) % 2 == 0
    noise = 0.01 * rng.standard_normal(40)
    dep = interaction(0.05 * high + noise, high, n_boot=1000)
    assert dep["contrast"] == pytest.approx(0.05, abs=0.01) and dep["ci95"][0] > 0
    # a uniform gain is called specific at about the CI's one-sided error rate (2.5 %)
    false = [interaction(0.05 + 0.01 * np.random.default_rng(s).standard_normal(40), high, n_boot=500, seed=s)
             ["ci95"][0] > 0 for s in range(200)]
    assert np.mean(false) < 0.07
    assert interaction(noise[:4], high[:4]) is None  # two rows per group: nothing to say
    factors = {"off_boresight_deg": np.where(high, 30.0, 0.0)}
    assert specificity("antenna_pattern", 0.05 * high + noise, factors, n_boot=500)["specific"]
    assert not specificity("antenna_pattern", 0.05 + noise, factors, n_boot=500)["specific"]
    assert specificity("noise", noise, factors) is None and "noise" not in EXPECTED_FACTOR


def test_far_pixels_are_more_than_far_rows_from_every_return_circularly():
    before = np.zeros((1, 64, 3))
    before[0, 10, 0] = before[0, 1, 1] = 0.5
    far = far_pixels(before)[0]
    assert not far[10 - FAR_ROWS:10 + FAR_ROWS + 1, 0].any() and far[:10 - FAR_ROWS, 0].all()
    assert far[10 + FAR_ROWS + 1:, 0].all()
    assert not far[64 - FAR_ROWS + 1:, 1].any() and not far[:1 + FAR_ROWS + 1, 1].any()  # wraps round zero
    assert far[1 + FAR_ROWS + 1:64 - FAR_ROWS + 1, 1].all() and far[:, 2].all()  # a column with no return


def test_far_contrast_credits_a_white_floor_and_not_a_spread():
    """Measured = returns + a white floor; a candidate that adds the floor everywhere gains most far from
    the returns, one that spreads the returns (a generic closer) gains only next to them."""
    rng = np.random.default_rng(1)
    n, rows = 12, np.arange(64)[None, :, None]
    centre = rng.integers(20, 44, (n, 1, 1))
    before = np.clip(1.0 - np.abs(rows - centre) / 3.0, 0.0, 1.0) * np.ones((1, 1, 8))
    floor = 0.2 + 0.02 * rng.standard_normal((n, 64, 8))
    measured = np.maximum(before, floor)
    white = np.maximum(before, 0.2)
    spread = np.where(np.abs(rows - centre) <= 4, white, before)  # the floor next to the returns only
    w = far_contrast(measured, before, white, n_boot=500)
    assert w["contrast"] > 0 and w["ci95"][0] > 0 and w["gain_high"] > 0.03
    s_ = far_contrast(measured, before, spread, n_boot=500)
    assert s_["ci95"][1] < 0 and s_["gain_high"] == 0.0  # nothing changes far from the returns
    assert pixel_specificity("noise", measured, before, white, n_boot=500)["specific"]
    assert pixel_specificity("palm", measured, before, white) is None
    assert far_contrast(measured[:2], before[:2], white[:2]) is None  # too few rows to say anything


_NOISE_REPORTS: dict[tuple[str, int], dict] = {}


def _noise_report(radar, chain, kind: str, seed: int) -> dict:
    """The validated report of noise vs palm (noise at its closed-form expectation) on 24 rows of data
    seed ``seed``: "noisy" (noise at 10 dB SNR) or "mirror" (an IQ mirror image, no noise); cached."""
    if (kind, seed) not in _NOISE_REPORTS:
        cfg = DiagnosisConfig(candidates=["noise", "palm"], radarweightnet=False, n_boot=500, noise_draws=0)
        data = (gap_data(radar, chain, 24, {"noise": {"snr_db": 10.0}}, seed=seed) if kind == "noisy" else
                gap_data(radar, chain, 24, {}, seed=seed, distort=lambda s: s + 0.3 * s.conj()))
        rep = diagnose(data, builder(radar, chain), {}, cfg, progress=False).report
        validate_report(rep, n_doppler=data.measured.shape[1], n_columns=data.measured.shape[2])
        _NOISE_REPORTS[kind, seed] = rep
    return _NOISE_REPORTS[kind, seed]


def _noise(rep: dict) -> dict:
    return next(c for c in rep["candidates"] if c["effect"] == "noise")["specificity"]


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_noise_candidate_named_for_a_gap_it_did_not_make_is_not_specific(radar, short_chain, seed):
    """Noise credited in noisy data comes far from the returns; on an IQ mirror image (no noise in the
    data), where noise's exact expectation closes a generic part, its credit comes next to the returns
    only: the evidence tells the two apart on every data seed (measured, seeds 1-5: far-minus-near
    contrast CI above 0 on noisy data, lower bound +0.0005 to +0.0016; below 0 on the mirror, upper
    bound -0.00003 to -0.00008)."""
    noisy_report = _noise_report(radar, short_chain, "noisy", seed)
    noisy, mirror = _noise(noisy_report), _noise(_noise_report(radar, short_chain, "mirror", seed))
    assert noisy_report["cause"] == "noise"
    assert noisy["specific"] and noisy["factor"] == "far_from_returns" and noisy["ci95"][0] > 0
    assert not mirror["specific"] and mirror["ci95"][1] < 0


# measured on data seeds 1-5: the mirror's cause is inconclusive, noise, inconclusive, none, inconclusive
MIRROR_NAMES_NOISE = ("known false positive (docs/gap_validation.md, 'Noise as a generic closer'): on data seed 2 noise's "
                      "expectation closes +0.033 [+0.012, +0.061] of the IQ-mirror gap and is named; the "
                      "specificity evidence flags it but is not part of the verdict")


@pytest.mark.parametrize("seed", [1, pytest.param(2, marks=pytest.mark.xfail(strict=True, reason=MIRROR_NAMES_NOISE)), 3])
def test_an_iq_mirror_gap_is_not_credited_to_noise(radar, short_chain, seed):
    assert _noise_report(radar, short_chain, "mirror", seed)["cause"] != "noise"


@pytest.mark.slow
def test_an_antenna_pattern_is_credited_off_boresight(radar, short_chain):
    """Rows spread over +-35 deg of azimuth with a strong antenna pattern: the antenna candidate's gain
    is larger off boresight; the report carries, validates and prints the evidence."""
    data = gap_data(radar, short_chain, 48, {"antenna_pattern": {"q": 8.0}}, seed=2)
    cfg = DiagnosisConfig(candidates=["antenna_pattern", "palm"], radarweightnet=False, n_boot=500, fit_rows=None)
    rep = diagnose(data, builder(radar, short_chain), {}, cfg, progress=False).report
    ant = next(c for c in rep["candidates"] if c["effect"] == "antenna_pattern")
    sp = ant["specificity"]
    assert sp["factor"] == "off_boresight_deg" and sp["contrast"] > 0 and sp["specific"], sp
    validate_report(rep, n_doppler=data.measured.shape[1], n_columns=data.measured.shape[2])
    assert "(off_boresight_deg)" in render(rep, {}, Path("."))
    bad = {**rep, "candidates": [{**ant, "specificity": {"factor": "x", "contrast": 0.1, "ci95": [0.2, 0.1]}}]}
    with pytest.raises(ReportError, match="specificity.ci95"):
        validate_report(bad, n_doppler=data.measured.shape[1], n_columns=data.measured.shape[2])
