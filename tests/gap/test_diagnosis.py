"""The diagnosis names an effect that is there, recovers its parameter roughly, and says "none" when
no candidate explains the gap; its report follows the contract."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from handradar.gap.data import GapData
from handradar.gap.diagnosis import Candidate, DiagnosisConfig, _evidence, diagnose
from handradar.gap.fit import GridFit, effect_grid
from handradar.gap.report import validate_report
from handradar.sim.effects import REGISTRY, Effect
from handradar.sim.effects.base import Param
from handradar.sim.simulator import Simulator
from tests.gap.conftest import builder, gap_data, rows

CANDIDATES = ["antenna_pattern", "palm", "noise", "multipath"]


def run(radar, chain, data, **kw):
    cfg = DiagnosisConfig(candidates=CANDIDATES, radarweightnet=False, n_boot=500, refine_rows=4, **kw)
    return diagnose(data, builder(radar, chain), {}, cfg, progress=False)


def test_names_the_effect_and_recovers_its_parameter(radar, short_chain):
    # the antenna's cos^q pattern at q = 6 (default 4; grid 0.5, 1, 2, 4, 8): hands spread over +-35 deg
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
    from handradar.data.splits import stratified_partition

    def stratified_split(labels, f, seed):
        return stratified_partition(labels, (f, 1 - f), seed, every_part=True)

    labels = np.repeat(np.arange(5), [7, 6, 5, 4, 1])
    cal, ev = stratified_split(labels, 0.5, seed=3)
    assert set(cal).isdisjoint(ev) and len(cal) + len(ev) == labels.size
    for c in range(4):
        n_cal = int((labels[cal] == c).sum())
        assert 1 <= n_cal <= (labels == c).sum() - 1 and abs(n_cal - 0.5 * (labels == c).sum()) <= 0.5
    again = stratified_split(labels, 0.5, seed=3)
    assert np.array_equal(again[0], cal) and np.array_equal(again[1], ev)
    assert not np.array_equal(stratified_split(labels, 0.5, seed=4)[0], cal)


def test_baseline_calibration_recovers_the_rcs_exponent(radar, short_chain):
    # "measured" = the paper's simulator with a less specular cylinder RCS (aspect exponent 0.5)
    rs, labels, meta = rows(radar, short_chain, 12, seed=4)
    with torch.no_grad():
        measured = Simulator(radar, short_chain, rcs_exponent=0.5)(
            torch.as_tensor(rs.skeletons), torch.as_tensor(rs.masks), times=torch.as_tensor(rs.times)).numpy()
    data = GapData(measured, rs, labels, meta, radar, short_chain, 100.0)
    uncalibrated = run(radar, short_chain, data, rcs_exponents=[1.0]).report
    assert uncalibrated["baseline"]["ssim"] < 0.99 and uncalibrated["baseline"]["calibration"]["grid"] == []
    rep = run(radar, short_chain, data, rcs_exponents=[1.0, 0.5, 0.25]).report
    validate_report(rep, n_columns=short_chain.n_columns)
    cal = rep["baseline"]["calibration"]
    assert cal["rcs_exponent"] == 0.5
    scores = {g["rcs_exponent"]: g["ssim"] for g in cal["grid"]}
    assert scores[0.5] == pytest.approx(1.0, abs=1e-4) and scores[0.5] > max(scores[1.0], scores[0.25])
    assert rep["baseline"]["ssim"] == pytest.approx(1.0, abs=1e-4)
    assert rep["cause"] == "none"  # the calibrated baseline leaves no gap for a candidate to close


def test_grid_overrides_replace_the_documented_values():
    g = effect_grid("multipath", {"multipath": {"height_m": [0.1, 0.2]}})
    params = REGISTRY["multipath"].params
    n_rest = len(params["reflection_coeff"].grid) * len(params["scale"].grid)
    assert {p["height_m"] for p in g} == {0.1, 0.2} and len(g) == 2 * n_rest
    assert effect_grid("palm") == REGISTRY["palm"].grid()
    with pytest.raises(ValueError, match="height_m"):
        effect_grid("multipath", {"multipath": {"height_m": [0.9]}})  # outside the bounds [0, 0.5]
    with pytest.raises(ValueError, match="unknown parameter"):
        effect_grid("multipath", {"multipath": {"depth_m": [0.1]}})


class _Broken(Effect):
    """A candidate whose simulation is not finite (a bug in a user's effect module)."""

    name = "broken"
    stage = "signal"
    order = 99
    params = {"level": Param(1.0, 0.0, 2.0, (0.5, 1.5))}
    fit = "grid"

    def apply_signal(self, signal, radar, chain):
        return signal * float("nan")


def test_a_candidate_with_non_finite_spectrograms_is_left_out(radar, short_chain, monkeypatch):
    monkeypatch.setitem(REGISTRY, "broken", _Broken)
    data = gap_data(radar, short_chain, 12, {"antenna_pattern": {"q": 6.0}})
    cfg = DiagnosisConfig(candidates=["antenna_pattern", "broken"], radarweightnet=False, n_boot=500)
    rep = diagnose(data, builder(radar, short_chain), {}, cfg, progress=False).report
    assert rep["cause"] == "antenna_pattern"
    assert [c["effect"] for c in rep["candidates"]] == ["antenna_pattern"]
    assert [e["effect"] for e in rep["excluded"]] == ["broken"] and "non-finite" in rep["excluded"][0]["reason"]


def test_a_significant_but_small_gain_names_no_cause():
    """The practical-relevance rule: a candidate whose gain is significant (CI above 0, clearly ahead of
    the runner-up) but below ``min_gap_closed`` is reported, not named; at or above it, it is named."""
    rng = np.random.default_rng(0)
    before = rng.uniform(0.8, 0.9, 200)
    gap = 1.0 - before

    def cand(name: str, closed: float) -> Candidate:
        ssim = before + closed * gap + rng.normal(0.0, 1e-4, before.shape)
        return Candidate(name, {}, GridFit(name, [], []), ssim, np.zeros_like(ssim), closed, (0.8 * closed, 1.2 * closed))

    small, other = cand("noise", 0.01), cand("palm", 0.0)
    cfg = DiagnosisConfig(n_boot=200)
    assert cfg.min_gap_closed == 0.02
    ev = _evidence(before, [small, other], cfg)
    assert ev["clearly_ahead"] and not ev["leader_significant"]
    assert _evidence(before, [small, other], DiagnosisConfig(n_boot=200, min_gap_closed=0.005))["leader_significant"]
