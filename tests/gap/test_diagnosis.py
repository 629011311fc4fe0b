"""The diagnosis names an effect that is there, recovers its parameter roughly, says "none" when no
candidate can explain a relevant part of the gap and "inconclusive" (with the recordings that would
decide it) when the data cannot tell; its report follows the contract."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from handradar.gap.data import GapData
from handradar.gap.diagnosis import (
    Candidate,
    DiagnosisConfig,
    _evidence,
    decide,
    diagnose,
    rows_to_decide,
)
from handradar.gap.fit import GridFit, effect_grid
from handradar.gap.markdown import render
from handradar.gap.report import fitted_simulator, validate_report
from handradar.metrics import per_example_ssim
from handradar.sim.effects import REGISTRY, Effect
from handradar.sim.effects.base import Param
from handradar.sim.simulator import Simulator
from tests.gap.conftest import builder, gap_data, rows, simulate

CANDIDATES = ["antenna_pattern", "palm", "noise", "multipath"]


def simulated(radar, chain, rs, **settings) -> np.ndarray:
    """The rows' spectrograms from the paper's simulator with other settings: "measured" data whose
    generic mismatch step 0 should recover."""
    with torch.no_grad():
        return Simulator(radar, chain, **settings)(torch.as_tensor(rs.skeletons), torch.as_tensor(rs.masks),
                                                   times=torch.as_tensor(rs.times)).numpy()


def run(radar, chain, data, **kw):
    cfg = DiagnosisConfig(candidates=CANDIDATES, radarweightnet=False, n_boot=500, refine_rows=4, **kw)
    return diagnose(data, builder(radar, chain), {}, cfg, progress=False)


def step_0(radar, chain, data: GapData, **grids) -> tuple[dict, dict, dict]:
    """Diagnose ``data`` on step 0's ``grids``: the validated report, its calibration and the mean SSIM
    of each grid point, keyed by the point's values in grid order."""
    rep = run(radar, chain, data, **grids).report
    validate_report(rep, n_columns=chain.n_columns)
    cal = rep["baseline"]["calibration"]
    return rep, cal, {tuple(v for k, v in g.items() if k != "ssim"): g["ssim"] for g in cal["grid"]}


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


# The noise candidate's own draws (Noise seed; 4 draws averaged) decide the verdict on the IQ-mirror
# gap of data seed 2. Measured for noise seeds 0-4 (0, 1 and 4 tested): gap_closed +0.006 [-0.011,
# +0.022] inconclusive, +0.032 [+0.002, +0.068] noise, +0.023 [+0.004, +0.042] noise, +0.016 [+0.003,
# +0.030] inconclusive, +0.026 [-0.003, +0.054] inconclusive; on data seeds 3 and 4, all five noise
# seeds give inconclusive or none.
NOISE_NAMED = "known false positive: a noise floor closes part of any low-level gap, and with these noise " \
              "draws its CI clears 0 and min_gap_closed (docs/gap_validation.md, 'Noise as a generic closer')"


@pytest.mark.parametrize("noise_seed", [0, pytest.param(1, marks=pytest.mark.xfail(strict=True, reason=NOISE_NAMED)), 4])
def test_gap_outside_the_vocabulary_names_no_effect(radar, short_chain, tmp_path, monkeypatch, noise_seed):
    # a receiver IQ imbalance (mirror image at the opposite Doppler): no candidate effect makes it
    # 24 rows: a percentile bootstrap over a handful of evaluation rows is too narrow to trust
    monkeypatch.setattr(REGISTRY["noise"].__init__, "__defaults__", (noise_seed, 1))  # the candidate's draws
    data = gap_data(radar, short_chain, 24, {}, seed=2, distort=lambda s: s + 0.3 * s.conj())
    rep = run(radar, short_chain, data).report
    validate_report(rep, n_columns=short_chain.n_columns)
    assert rep["baseline"]["ssim"] < 0.99  # there is a gap ...
    assert not any(c["significant"] for c in rep["candidates"])  # ... that nothing in the vocabulary explains
    assert rep["cause"] in ("none", "inconclusive"), rep["evidence"]
    if rep["cause"] == "inconclusive":
        # on 12 evaluation rows the leader's CI reaches past min_gap_closed = 0.02 (seed 0) or down to 0
        # (seed 4): more rows would show its upper bound below 0.02, or its CI above 0 and its lead
        ev, top = rep["evidence"], rep["candidates"][0]
        assert ev["leader"] == top["effect"] == "noise"
        below = top["gap_closed"] < 0.02
        assert ("upper 95 % bound" in ev["decides"]) == below and ("CI of gap_closed above 0" in ev["decides"]) != below
        assert ev["evaluation_rows_needed"] > rep["n_evaluation"] and ev["recordings_needed"] > len(data)
        md = render(rep, {}, tmp_path)
        assert "**Cause: inconclusive**" in md and f"About {ev['recordings_needed']} recordings" in md


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
    measured = simulated(radar, short_chain, rs, rcs_exponent=0.5)
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


def test_baseline_calibration_recovers_a_metacarpal_gain(radar, short_chain, tmp_path):
    # "measured" = the paper's simulator with the four finger metacarpals at half amplitude (as if the
    # palm's flesh half buried them); step 0 finds the factor on the joint (exponent, gain) grid. The
    # hands also move to and from the radar: a still palm is static clutter, which the chain removes
    rs, labels, meta = rows(radar, short_chain, 12, seed=5)
    rs.skeletons = (rs.skeletons + 0.04 * np.sin(2 * np.pi * 3.0 * rs.times)[None, :, None, None, None]
                    * np.array([0.0, 0.0, 1.0])).astype(np.float32)
    data = GapData(simulated(radar, short_chain, rs, metacarpal_gain=0.5), rs, labels, meta, radar, short_chain, 100.0)
    rep, cal, scores = step_0(radar, short_chain, data, rcs_exponents=[1.0, 0.5], metacarpal_gains=[1.0, 0.5, 0.0])
    assert (cal["rcs_exponent"], cal["metacarpal_gain"]) == (1.0, 0.5) and len(cal["grid"]) == 6
    assert scores[1.0, 0.5] == pytest.approx(1.0, abs=1e-4) and max(v for k, v in scores.items() if k != (1.0, 0.5)) < 0.999
    assert fitted_simulator(rep)["metacarpal_gain"] == 0.5
    text = render(rep, {}, tmp_path)
    assert "and the metacarpals' amplitude to 0.5" in text and "(1, 1) = the paper's model" in text
    with pytest.raises(ValueError, match="metacarpal_gains"):
        DiagnosisConfig.from_mapping({"metacarpal_gains": [1.5]})


def test_baseline_calibration_recovers_a_coherence(radar, short_chain, tmp_path):
    # "measured" = the paper's simulator with the bones' cross terms averaged out (their relative phases
    # unknown: Simulator coherence 0); step 0 finds it on the joint (exponent, coherence) grid
    rs, labels, meta = rows(radar, short_chain, 12, seed=5)
    data = GapData(simulated(radar, short_chain, rs, coherence=0.0), rs, labels, meta, radar, short_chain, 100.0)
    rep, cal, scores = step_0(radar, short_chain, data, rcs_exponents=[1.0, 0.5], coherences=[1.0, 0.5, 0.0])
    assert (cal["rcs_exponent"], cal["coherence"]) == (1.0, 0.0) and len(cal["grid"]) == 6
    assert scores[1.0, 0.0] == pytest.approx(1.0, abs=1e-4) and max(v for k, v in scores.items() if k != (1.0, 0.0)) < 0.999
    assert fitted_simulator(rep)["coherence"] == 0.0
    assert "and the bones' cross terms kept at 0" in render(rep, {}, tmp_path)
    with pytest.raises(ValueError, match="coherences"):
        DiagnosisConfig.from_mapping({"coherences": [1.5]})


def test_step_0_fits_the_baselines_noise_and_compares_its_expected_spectrogram(radar, short_chain, tmp_path):
    # "measured" = one noise draw at 5 dB (like a measurement); the baseline's noise sits at its default 20 dB
    data = gap_data(radar, short_chain, 12, {"noise": {"snr_db": 5.0}}, seed=3)
    cfg = DiagnosisConfig(candidates=["palm"], radarweightnet=False, n_boot=200)
    d = diagnose(data, builder(radar, short_chain), {"noise": {}}, cfg, progress=False)
    rep = d.report
    validate_report(rep, n_columns=short_chain.n_columns)
    cal = rep["baseline"]["calibration"]
    snr = cal["effects"]["noise"]["snr_db"]
    assert abs(snr - 5.0) <= 5.0  # a grid step (5 dB) from the truth, far from the default 20 dB
    assert rep["baseline"]["effects"] == cal["effects"]
    assert cal["effect_grids"]["noise"]["best"] == {"snr_db": snr}
    assert "noise snr_db=" in render(rep, {}, tmp_path)
    # the evaluation rows as the unfitted baseline scored them before: default SNR, one draw
    rs = data.rows.take(d.evaluation)
    target = torch.as_tensor(d.measured)
    unfitted = float(per_example_ssim(target, torch.as_tensor(simulate(radar, short_chain, rs, {"noise": {}}))).mean())
    fitted_single = simulate(radar, short_chain, rs, {"noise": {"snr_db": snr}})
    assert rep["baseline"]["ssim"] > unfitted + 0.1
    assert rep["baseline"]["ssim"] > float(per_example_ssim(target, torch.as_tensor(fitted_single)).mean())
    # the baseline is the expected spectrogram (noise_draws draws averaged in power), closer to the
    # 64-draw average than one draw at the same SNR is
    expected = simulate(radar, short_chain, rs, {"noise": {"snr_db": snr, "draws": 64}})
    assert np.abs(d.baseline - expected).mean() < 0.8 * np.abs(fitted_single - expected).mean()


def test_step_0_recovers_a_baseline_effects_parameter(radar, short_chain):
    # measured with the antenna's cos^q pattern at q = 8; the baseline has it at its default q = 4
    data = gap_data(radar, short_chain, 12, {"antenna_pattern": {"q": 8.0}})
    cfg = DiagnosisConfig(candidates=["palm", "noise"], radarweightnet=False, n_boot=200)
    rep = diagnose(data, builder(radar, short_chain), {"antenna_pattern": {}}, cfg, progress=False).report
    validate_report(rep, n_columns=short_chain.n_columns)
    assert rep["baseline"]["calibration"]["effects"] == {"antenna_pattern": {"q": 8.0}}
    assert rep["baseline"]["effects"] == {"antenna_pattern": {"q": 8.0}}
    assert rep["baseline"]["calibration"]["rcs_exponent"] == 1.0
    assert rep["baseline"]["ssim"] == pytest.approx(1.0, abs=1e-4) and rep["cause"] == "none"
    sim = fitted_simulator(rep, {})
    assert sim["effects"] == ["antenna_pattern"] and sim["effect_params"] == {"antenna_pattern": {"q": 8.0}}


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

    def apply_signal(self, signal, radar, chain, power_scale=None):
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
    the runner-up) but bounded below ``min_gap_closed`` gives "none"; at or above it, it is named; a
    leader whose CI reaches past the threshold without excluding 0 gives "inconclusive"."""
    rng = np.random.default_rng(0)
    before = rng.uniform(0.8, 0.9, 200)
    gap = 1.0 - before

    def cand(name: str, closed: float, ci95: tuple[float, float] | None = None) -> Candidate:
        ssim = before + closed * gap + rng.normal(0.0, 1e-4, before.shape)
        return Candidate(name, {}, GridFit(name, [], []), ssim, np.zeros_like(ssim), closed,
                         ci95 or (0.8 * closed, 1.2 * closed))

    small, other = cand("noise", 0.01), cand("palm", 0.0)
    cfg = DiagnosisConfig(n_boot=200)
    assert cfg.min_gap_closed == 0.02
    cause, ev = _evidence(before, [small, other], cfg)
    assert ev["clearly_ahead"] and not ev["leader_significant"]
    assert cause == "none" and ev["recordings_needed"] is None  # its CI [0.008, 0.012] ends below 0.02
    cause, ev = _evidence(before, [small, other], DiagnosisConfig(n_boot=200, min_gap_closed=0.005))
    assert cause == "noise" and ev["leader_significant"]
    wide = cand("noise", 0.03, (-0.02, 0.08))  # clearly ahead of palm, but its own CI contains 0
    cause, ev = _evidence(before, [wide, other], cfg)
    assert ev["clearly_ahead"] and cause == "inconclusive"
    # the CI's half-width 0.05 (se 0.05 / 1.96) against the margin 0.03, from 200 evaluation rows, at 80 %
    # power: 200 * ((1.96 + 0.8416) / 1.96 * 5/3)^2 = 1135.1 -> 1136 rows; over calibration + evaluation
    # at fraction 0.5: 2270.2 -> 2271 recordings
    assert (ev["evaluation_rows_needed"], ev["recordings_needed"]) == (1136, 2271)
    assert "CI of gap_closed above 0" in ev["decides"]


# the sample size for a two-sided 95 % test at 80 % power, against the rows where the half-width just
# reaches the margin: ((z_0.975 + z_0.8) / z_0.975)^2 (scipy.stats.norm.ppf(0.8) = 0.8416)
POWER = ((1.96 + 0.8416) / 1.96) ** 2


def test_rows_to_decide_scales_the_half_width_with_one_over_sqrt_rows():
    # [0.01, 0.05] from 50 rows: half-width 0.02; shrinking it to a margin of 0.01 takes 4x the rows, and
    # clearing the bound with 80 % probability POWER (2.04) times that
    assert rows_to_decide(50, (0.01, 0.05), 0.01) == pytest.approx(200.0 * POWER)
    assert POWER == pytest.approx(2.0431, abs=1e-4)
    assert rows_to_decide(50, (-0.01, 0.05), 0.06) == 51.0  # a skewed CI: never fewer rows than failed
    assert rows_to_decide(50, (0.01, 0.05), 0.0) is None
    assert rows_to_decide(50, (0.01, 0.05), -0.01) is None
    assert rows_to_decide(50, (float("nan"), 0.05), 0.01) is None


DECIDE = {"min_gap_closed": 0.02, "n_eval": 60, "calibration_fraction": 0.5}


def test_decide_names_a_significant_leader_clearly_ahead():
    v = decide("palm", 0.10, (0.05, 0.15), 0.04, (0.01, 0.07), **DECIDE)
    assert v == {"cause": "palm", "decides": None, "evaluation_rows_needed": None, "recordings_needed": None}
    assert decide("palm", 0.10, (0.05, 0.15), None, None, **DECIDE)["cause"] == "palm"  # no runner-up


def test_decide_says_none_when_the_leader_is_bounded_below_the_threshold():
    # significant (CI above 0) but its upper bound 0.016 < 0.02; the lead over the runner-up is irrelevant
    v = decide("noise", 0.010, (0.004, 0.016), 0.005, (-0.002, 0.012), **DECIDE)
    assert v == {"cause": "none", "decides": None, "evaluation_rows_needed": None, "recordings_needed": None}
    assert decide("noise", 0.0, (0.0, 0.0), 0.0, (0.0, 0.0), **DECIDE)["cause"] == "none"  # no gain at all


@pytest.mark.parametrize("args, kw, rows, recordings, shows", [
    # (each: 60 rows x (half-width / margin)^2 x POWER 2.0431, the 80 % power factor)
    # straddles the threshold, estimate below it: prove the upper bound below 0.02. Half-width 0.01 against
    # 0.02 - 0.015 = 0.005: 60 * 2^2 * 2.0431 = 490.4 -> 491 rows (the lead's CI, containing 0, does not
    # count: a "none" needs no separation from the runner-up)
    (("noise", 0.015, (0.005, 0.025), 0.002, (-0.01, 0.014)), {}, 491, 981, "upper 95 % bound"),
    # relevant and significant, lead CI contains 0: half-width 0.015 against the lead 0.01:
    # 60 * 1.5^2 * 2.0431 = 275.8 -> 276 rows
    (("palm", 0.05, (0.03, 0.07), 0.01, (-0.005, 0.025)), {}, 276, 552, "lead over the runner-up"),
    # ... at a calibration fraction of 0.6: 275.8 / 0.4 = 689.6 -> 690 recordings
    (("palm", 0.05, (0.03, 0.07), 0.01, (-0.005, 0.025)), {"calibration_fraction": 0.6}, 276, 690, "lead"),
    # both fail; the leader's own CI needs more: half-width 0.05 against 0.03: 60 * (5/3)^2 * 2.0431 = 340.5
    # -> 341 rows, the lead's 0.03 against 0.02: 275.8; at calibration fraction 0.25: 340.5 / 0.75 = 454.0 -> 455
    (("palm", 0.03, (-0.02, 0.08), 0.02, (-0.01, 0.05)), {"calibration_fraction": 0.25}, 341, 455,
     "CI of gap_closed above 0 and"),
    # no runner-up, own CI contains 0: half-width 0.04 against 0.03: 60 * (4/3)^2 * 2.0431 = 217.9 -> 218 rows
    (("palm", 0.03, (-0.01, 0.07), None, None), {}, 218, 436, "CI of gap_closed above 0"),
])
def test_decide_is_inconclusive_with_the_recordings_that_would_decide(args, kw, rows, recordings, shows):
    v = decide(*args, **{**DECIDE, **kw})
    assert v["cause"] == "inconclusive"
    assert (v["evaluation_rows_needed"], v["recordings_needed"]) == (rows, recordings)
    assert shows in v["decides"] and "no estimate" not in v["decides"]


def test_decide_gives_no_estimate_when_a_margin_is_not_positive():
    # relevant and significant, but tied with the runner-up (lead 0): no number of rows separates them
    v = decide("palm", 0.05, (0.03, 0.07), 0.0, (-0.01, 0.01), **DECIDE)
    assert v["cause"] == "inconclusive" and v["recordings_needed"] is None and v["evaluation_rows_needed"] is None
    assert "no estimate" in v["decides"] and "lead over the runner-up" in v["decides"]


@pytest.mark.parametrize("lead, rows", [
    # lead CI half-width 0.015: a lead of 0.0022 needs 60 * (0.015 / 0.0022)^2 * 2.0431 = 5698.6 -> 5699 rows,
    # under 100x the 60 at hand: still estimated
    (0.0022, 5699),
    # a lead of 0.0021 needs 60 * (0.015 / 0.0021)^2 * 2.0431 = 6254.5 rows > 100x: no estimate
    (0.0021, None),
])
def test_decide_gives_no_estimate_beyond_a_hundred_times_the_rows(lead, rows):
    # the held-out benchmark's multipath leader, 0.0004 under the threshold, was given 355915 recordings
    v = decide("multipath", 0.05, (0.03, 0.07), lead, (lead - 0.015, lead + 0.015), **DECIDE)
    assert v["cause"] == "inconclusive" and v["evaluation_rows_needed"] == rows
    assert ("tied at any practical size" in v["decides"]) == (rows is None)
