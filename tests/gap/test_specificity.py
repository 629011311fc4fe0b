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
    interaction,
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
