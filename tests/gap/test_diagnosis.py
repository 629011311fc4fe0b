"""The diagnosis names an effect that is there, recovers its parameter roughly, and says "none" when
no candidate explains the gap; its report follows the contract."""

from __future__ import annotations

import numpy as np
import pytest

from handradar.gap.diagnosis import DiagnosisConfig, diagnose
from handradar.gap.report import validate_report
from tests.gap.conftest import builder, gap_data

CANDIDATES = ["antenna_pattern", "palm", "noise", "multipath"]


def run(radar, chain, data, **kw):
    cfg = DiagnosisConfig(candidates=CANDIDATES, radarweightnet=False, n_boot=500, refine_rows=4, **kw)
    return diagnose(data, builder(radar, chain), {}, cfg, progress=False)


def test_names_the_effect_and_recovers_its_parameter(radar, short_chain):
    # the antenna's cos^q pattern at q = 6 (default 4; grid 1, 2, 4, 8): hands spread over +-35 deg
    data = gap_data(radar, short_chain, 12, {"antenna_pattern": {"q": 6.0}})
    d = run(radar, short_chain, data, refine_steps=4)
    rep = d.report
    validate_report(rep, n_columns=short_chain.n_columns)
    assert rep["cause"] == "antenna_pattern"
    top = rep["candidates"][0]
    assert top["effect"] == "antenna_pattern" and top["ci95"][0] > 0.5
    assert 4.5 < top["params"]["q"] < 7.5  # the grid's 4 or 8, refined toward 6
    assert rep["evidence"]["clearly_ahead"] and rep["evidence"]["lead_ci95"][0] > 0
    assert rep["after"]["effects"][0] == "antenna_pattern" and rep["after"]["gap_closed"] > 0.5
    assert rep["n_calibration"] + rep["n_evaluation"] == 12
    assert set(d.calibration).isdisjoint(d.evaluation)


def test_null_data_give_none(radar, short_chain):
    data = gap_data(radar, short_chain, 8, {})  # measured = the baseline simulator itself
    rep = run(radar, short_chain, data).report
    validate_report(rep, n_columns=short_chain.n_columns)
    assert rep["baseline"]["ssim"] == pytest.approx(1.0, abs=1e-4)
    assert rep["cause"] == "none" and rep["after"]["effects"] == []
    assert all(c["gap_closed"] <= 1e-6 for c in rep["candidates"])


def test_gap_outside_the_vocabulary_gives_none(radar, short_chain):
    # a receiver IQ imbalance (mirror image at the opposite Doppler): no candidate effect makes it
    # 24 rows: a percentile bootstrap over a handful of evaluation rows is too narrow to trust
    data = gap_data(radar, short_chain, 24, {}, seed=2, distort=lambda s: s + 0.3 * s.conj())
    rep = run(radar, short_chain, data).report
    assert rep["baseline"]["ssim"] < 0.99  # there is a gap ...
    assert rep["cause"] == "none"  # ... that nothing in the vocabulary explains
    assert not any(c["significant"] for c in rep["candidates"])


def test_split_is_seeded_stratified_and_disjoint():
    from handradar.gap.data import stratified_split

    labels = np.repeat(np.arange(5), [7, 6, 5, 4, 1])
    cal, ev = stratified_split(labels, 0.5, seed=3)
    assert set(cal).isdisjoint(ev) and len(cal) + len(ev) == labels.size
    for c in range(4):
        n_cal = int((labels[cal] == c).sum())
        assert 1 <= n_cal <= (labels == c).sum() - 1 and abs(n_cal - 0.5 * (labels == c).sum()) <= 0.5
    again = stratified_split(labels, 0.5, seed=3)
    assert np.array_equal(again[0], cal) and np.array_equal(again[1], ev)
    assert not np.array_equal(stratified_split(labels, 0.5, seed=4)[0], cal)
