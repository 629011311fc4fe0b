"""A noise level that follows each row's measured floor (diagnose.noise_floor): the floor read from
speckle statistics against the closed form, per-row offsets through the engine, and a diagnosis whose
rows carry different noise levels."""

from __future__ import annotations

import numpy as np
import torch

from handradar.gap.data import GapData
from handradar.gap.diagnosis import DiagnosisConfig, diagnose
from handradar.gap.engine import VariantEngine
from handradar.gap.fit import floor_snr_offsets, measured_floor_db
from handradar.gap.markdown import render
from handradar.gap.report import validate_report
from handradar.radar.chain import power_to_unit
from tests.gap.conftest import builder, rows, simulate


def test_floor_level_from_speckle_against_the_closed_form(chain):
    """Exponential speckle of mean N times the display floor F (30 dB below a single peak pixel), from
    mostly below the floor to far above it: the estimate returns 10 log10 N."""
    rng = np.random.default_rng(0)
    levels_db = np.array([-6.0, -2.0, 0.0, 3.0, 6.0, 12.0, 20.0])
    floor = 10.0 ** (-chain.dynamic_range_db / 10.0)
    power = rng.exponential(1.0, (len(levels_db), 64, 256)) * (floor * 10.0 ** (levels_db / 10.0))[:, None, None]
    power[:, 0, 0] = 1.0  # the peak, above every speckle draw
    measured = power_to_unit(torch.as_tensor(power), chain).numpy()
    simulated = np.zeros_like(measured)
    simulated[:, :4] = 0.5  # a modelled return: those pixels are not read
    got, hidden = measured_floor_db(measured, simulated, chain.dynamic_range_db)
    np.testing.assert_allclose(got, levels_db, atol=0.1)
    assert not hidden.any()
    # faint returns the simulation lacks, at slow speeds (inner Doppler half, zero Doppler at row 32):
    # not noise, and not read as such; the same returns at fast speeds are
    faint = measured.copy()
    faint[:, 20:44] = np.maximum(faint[:, 20:44], 0.3)
    np.testing.assert_allclose(measured_floor_db(faint, simulated, chain.dynamic_range_db)[0], levels_db, atol=0.1)
    faint = measured.copy()
    faint[:, 50:64] = np.maximum(faint[:, 50:64], 0.9)
    assert (measured_floor_db(faint, simulated, chain.dynamic_range_db)[0] > levels_db + 1.0).all()
    # nothing above the floor: the noise is below it, at most the level of one pixel expected above it
    # among the row's n floor pixels; no floor pixel left: unknown
    measured[0] = 0.0
    simulated[1] = 1.0
    got, hidden = measured_floor_db(measured, simulated, chain.dynamic_range_db)
    n_floor = (33 - 4) * 256  # the outer Doppler half (|row - 32| >= 16: rows 0-16, 48-63) less the 4 modelled
    np.testing.assert_allclose(got[0], -10.0 * np.log10(np.log(n_floor)))
    assert hidden.tolist() == [True] + [False] * 6
    assert np.isnan(got[1]) and np.isfinite(got[2:]).all()
    # a row 20 dB above the floor observed under a noise-free one: their offsets differ by the levels
    off = floor_snr_offsets(got)
    ok = np.isfinite(got)
    np.testing.assert_allclose(off, np.where(ok, np.median(got[ok]) - got, 0.0))
    assert off[1] == 0.0 and off[0] - off[-1] > 25.0
    assert not floor_snr_offsets(np.full(3, np.nan)).any()


def test_engine_applies_each_rows_snr_offset(radar, short_chain):
    rs, _, _ = rows(radar, short_chain, 4, seed=2)
    rs.snr_offset_db = np.array([-6.0, 0.0, 4.0, 10.0])
    build = builder(radar, short_chain).replace(noise_draws=0)  # the closed form: no draws to align
    got = VariantEngine(build, {}, rs, batch_size=4).spectrograms([{"noise": {"snr_db": 10.0}}])[0]
    for i, off in enumerate(rs.snr_offset_db):
        one = rs.take(np.array([i]))
        one.snr_offset_db = None
        want = VariantEngine(build, {}, one).spectrograms([{"noise": {"snr_db": 10.0 + off}}])[0]
        np.testing.assert_allclose(got[i], want[0], atol=1e-5)


def test_noise_at_levels_that_differ_by_row_is_followed(radar, short_chain, tmp_path):
    """Rows measured at 0 dB and at 20 dB: one fitted SNR fits neither half; following each row's
    measured floor, the noise candidate closes more of the gap and the offsets split the halves."""
    rs, labels, meta = rows(radar, short_chain, 16, seed=4)
    snr = np.where(np.arange(16) % 8 < 4, 0.0, 20.0)  # half of every gesture at each level
    halves = [np.flatnonzero(snr == level) for level in (0.0, 20.0)]
    measured = np.concatenate([simulate(radar, short_chain, rs.take(idx), {"noise": {"snr_db": snr[idx[0]]}})
                               for idx in halves])[np.argsort(np.concatenate(halves))]  # back in row order
    data = GapData(measured, rs, labels, meta, radar, short_chain, 100.0)
    closed = {}
    for follow in (False, True):
        cfg = DiagnosisConfig(candidates=["noise"], radarweightnet=False, n_boot=200, rcs_exponents=[1.0],
                              folds=2, noise_floor=follow)
        rep = diagnose(data, builder(radar, short_chain), {}, cfg, progress=False).report
        validate_report(rep, n_columns=short_chain.n_columns)
        closed[follow] = rep["candidates"][0]["gap_closed"]
    assert data.rows.snr_offset_db is not None
    assert data.rows.snr_offset_db[snr == 0.0].mean() < data.rows.snr_offset_db[snr == 20.0].mean() - 5.0
    assert rep["baseline"]["calibration"]["noise_floor"]["rows_observed"] >= 8
    assert "follows each row's measured floor" in render(rep, {}, tmp_path)
    assert closed[True] > closed[False] + 0.05
