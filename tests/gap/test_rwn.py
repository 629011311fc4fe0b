"""The RadarWeightNet readout of a diagnosis (handradar.gap.rwn): per-slot amplitudes against the
antenna pattern in closed form, the weight correlation against numpy, and the readout's figures on
data whose gap a per-bone weighting can close."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from handradar.gap.diagnosis import DiagnosisConfig, diagnose
from handradar.gap.report import validate_report
from handradar.gap.rwn import _pearson, slot_amplitudes
from handradar.hand.skeleton import BONE_CHILD, BONE_PARENT
from handradar.sim.factory import SimFactory
from tests.gap.conftest import builder, gap_data, rows


def test_slot_amplitudes_follow_the_antenna_pattern_in_closed_form(radar, short_chain):
    """A direct path's amplitude is scaled by sqrt(G(theta)) twice, G = cos^q of the bone midpoint's
    angle off boresight: the ratio of slot amplitudes with and without the pattern is cos(theta)^q.
    Slots of an untracked hand are 0."""
    rs, _, _ = rows(radar, short_chain, 2, seed=1)  # row 0: one hand, row 1: two hands
    sk, m, t = (torch.as_tensor(a) for a in (rs.skeletons, rs.masks, rs.times))
    factory = SimFactory(radar, short_chain)
    plain, q = factory({}), 4.0
    with torch.no_grad():
        a0 = slot_amplitudes(plain, sk, m, t, None).double().numpy()
        a1 = slot_amplitudes(factory({"antenna_pattern": {"q": q}}), sk, m, t, None).double().numpy()
        joints = plain.context(sk, m, times=t).joints.double().numpy()  # (B, T, 2, 21, 3) as simulated
    assert a0.shape == (2, len(rs.times), 38)
    mid = 0.5 * (joints[..., BONE_PARENT, :] + joints[..., BONE_CHILD, :])  # (B, T, 2, 19, 3)
    with np.errstate(invalid="ignore"):  # the untracked hand's joints are all 0
        cos = mid[..., 2] / np.linalg.norm(mid, axis=-1)
    expected = (cos**q).reshape(2, len(rs.times), 38)
    tracked = a0 > 0
    assert tracked[1].all() and tracked[0, :, :19].all() and not tracked[0, :, 19:].any()
    np.testing.assert_allclose(a1[tracked] / a0[tracked], expected[tracked], rtol=1e-5)
    assert expected[tracked].min() < 0.9  # hands off boresight: the check is not 1 == 1


def test_weight_correlation_is_pearson_over_valid_entries_after_removing_each_rows_mean():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(3, 5, 4)), rng.normal(size=(3, 5, 4))
    valid = rng.random((3, 5, 4)) > 0.3
    b = b + 0.8 * a + np.arange(3)[:, None, None] * 5.0  # a per-row offset, which must not count
    centre = lambda x: np.concatenate([x[i][valid[i]] - x[i][valid[i]].mean() for i in range(3)])
    expected = np.corrcoef(centre(a), centre(b))[0, 1]
    got = _pearson(torch.as_tensor(a), torch.as_tensor(b), torch.as_tensor(valid))
    assert got == pytest.approx(expected, rel=1e-9) and 0.3 < got < 1.0
    assert _pearson(torch.as_tensor(a), torch.zeros(3, 5, 4, dtype=torch.float64), torch.as_tensor(valid)) is None


def test_readout_closes_a_per_bone_gap_and_resembles_the_antenna(radar, short_chain, tmp_path):
    """Measured = the simulator with a strong antenna pattern (a per-bone amplitude change a learned
    weighting can make): RadarWeightNet closes part of the gap, its CI brackets the estimate, and its
    log weights correlate positively with the antenna's amplitude change (palm adds unweighted points:
    no correlation)."""
    data = gap_data(radar, short_chain, 16, {"antenna_pattern": {"q": 8.0}}, seed=3)
    cfg = DiagnosisConfig(candidates=["antenna_pattern", "palm"], radarweightnet=True, n_boot=300,
                          rcs_exponents=[1.0], rwn_epochs=25, rwn_hidden=16, rwn_lr=1e-2, rwn_batch_size=4)
    d = diagnose(data, builder(radar, short_chain), {}, cfg, progress=False)
    validate_report(d.report, n_columns=short_chain.n_columns)
    rwn = d.report["radarweightnet"]
    assert rwn["train_rows"] == d.report["n_calibration"] and rwn["epochs"] == 25
    # measured on data seeds 1-4: gap_closed +0.13, +0.18, +0.06, +0.68 (8 evaluation rows: wide CIs);
    # final training loss 0.003-0.008 against the baseline's 0.023-0.029; correlation 0.16-0.60
    assert rwn["ci95"][0] <= rwn["gap_closed"] <= rwn["ci95"][1] and rwn["gap_closed"] > 0, rwn
    assert 0.0 <= rwn["final_train_loss"] < 0.5 * (1.0 - d.report["baseline"]["ssim"])  # it learned the rows
    assert rwn["weight_correlation"]["palm"] is None and rwn["weight_correlation"]["antenna_pattern"] > 0.1, rwn
    assert rwn["most_correlated"] == "antenna_pattern" and rwn["best_effect"] == "antenna_pattern"
    assert d.rwn.shape == (d.report["n_evaluation"], *data.measured.shape[1:]) and np.isfinite(d.rwn).all()
