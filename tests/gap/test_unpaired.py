"""The unpaired gap report (handradar.gap.unpaired): its statistics against closed forms, and its ranking."""

from __future__ import annotations

import json

import numpy as np
import pytest

from handradar.gap.unpaired import (
    burst_count,
    burst_span,
    cohen_d,
    doppler_centroid,
    doppler_reach,
    doppler_spread,
    moving_share,
    unpaired_gap,
    write_unpaired_gap,
    zero_band_share,
)


def test_statistics_closed_forms():
    x = np.zeros((1, 32, 10))
    x[0, 16 + 5, :] = 1.0                         # all energy 5 rows above zero (row 16)
    assert doppler_centroid(x)[0] == pytest.approx(5.0)
    assert doppler_spread(x)[0] == pytest.approx(0.0)
    assert zero_band_share(x)[0] == 0.0
    y = np.zeros((1, 32, 10))
    y[0, 16 - 3, :4] = y[0, 16 + 3, :4] = 1.0     # two equal lines at -3 and +3 rows, in 4 of 10 columns
    assert doppler_centroid(y)[0] == pytest.approx(0.0) and doppler_spread(y)[0] == pytest.approx(3.0)
    assert moving_share(y)[0] == pytest.approx(0.4)
    z = np.zeros((1, 32, 10))
    z[0, 15:18] = 1.0                              # the zero band only
    assert zero_band_share(z)[0] == pytest.approx(1.0)
    assert cohen_d(np.array([0.0, 2.0]), np.array([2.0, 4.0])) == pytest.approx(2.0 / np.sqrt(2.0))


def test_bursts_and_reach_of_known_lobes():
    """Lobes of known place: Gaussian in time (sigma 2 columns) and in Doppler (sigma 2 rows) over a background
    of 0.1 with small noise. Two lobes of height 1 at columns 20 and 38 (and one of 0.2 at column 50, below the
    prominence) are 2 bursts 18 columns apart; a lobe centred 12 rows from zero reaches the last row where the
    Gaussian stays above half its height: 12 + floor(2 sqrt(2 ln 2)) = 14 rows."""
    rows, cols = np.arange(64)[:, None] - 32, np.arange(64)[None, :]
    rng = np.random.default_rng(0)

    def lobe(row: float, col: float, height: float = 1.0) -> np.ndarray:
        return height * np.exp(-((rows - row) ** 2 + (cols - col) ** 2) / 8.0)

    x = 0.1 + lobe(12, 20) + lobe(-9, 38) + lobe(8, 50, 0.2) + rng.uniform(0, 0.01, (64, 64))
    assert burst_count(x[None])[0] == 2 and burst_span(x[None])[0] == 18
    assert doppler_reach(x[None])[0] == 12 + np.floor(2 * np.sqrt(2 * np.log(2)))
    one = 0.1 + lobe(-6, 30) + rng.uniform(0, 0.01, (64, 64))
    assert burst_count(one[None])[0] == 1 and burst_span(one[None])[0] == 0 and doppler_reach(one[None])[0] == 8
    assert burst_count(np.full((2, 64, 64), 0.1)).tolist() == [0, 0]    # nothing moves: no burst, no reach


def test_report_names_the_shifted_class_and_statistic(tmp_path):
    rng = np.random.default_rng(0)
    real = rng.uniform(0, 0.2, (60, 32, 16))
    labels = np.repeat(np.arange(3), 20)
    for i in range(60):
        real[i, 16 + 4 + rng.integers(-1, 2), 4:12] = 1.0   # every class: a line 4 rows above zero
    synth = real.copy()
    synth[labels == 2] = np.roll(real[labels == 2], -8, axis=1)   # class 2's synthetic: 4 rows below zero instead
    report = unpaired_gap(real, labels, synth, labels, ["a", "b", "c"])
    assert report["classes"]["a"]["mean_image_gap"] == pytest.approx(0.0, abs=1e-6)
    assert report["classes"]["c"]["mean_image_gap"] > 0.3
    assert report["classes"]["a"]["spread_image_gap"] == pytest.approx(0.0, abs=1e-6)
    assert report["classes"]["c"]["spread_image_gap"] > 0.3  # the line's row jitter moved with it
    top = report["largest"][0]
    assert (top["class"], top["statistic"]) == ("c", "doppler_centroid") and top["d"] < -5
    assert top["measured"] > 0 > top["synthetic"]  # above zero measured, below it synthetic (noise dilutes both)
    files = write_unpaired_gap(real, labels, synth, labels, ["a", "b", "c"], tmp_path)
    assert [f.name for f in files] == ["unpaired_gap.json", "unpaired_gap.md", "class_means.png"]
    assert json.loads(files[0].read_text())["largest"][0]["class"] == "c"
    assert "| c | doppler_centroid |" in files[1].read_text()
    assert "| class | doppler_reach | burst_count | burst_span |" in files[1].read_text()
    with pytest.raises(ValueError, match="class 'c' has 20 measured and 0 synthetic rows"):
        unpaired_gap(real, labels, synth[:40], labels[:40], ["a", "b", "c"])


def test_report_names_the_processing_step_that_explains_the_difference(tmp_path):
    """Measured rows scaled per frame (each column to its own peak), synthetic rows per image: of the steps switched
    on alone, per-frame scaling explains each class's difference (its class mean equals the measured one); where
    the synthetic rows already match, no step is named."""
    import torch

    from handradar.radar.chain import ChainConfig, power_to_unit
    from handradar.synthesis.measured import DEEP_FLOOR_DB, finish_rows, one_step_rows

    rng = np.random.default_rng(0)
    labels = np.repeat(np.arange(2), 10)
    power = 1e-3 + rng.exponential(size=(20, 32, 16)) * 1e-2
    for i, c in enumerate(labels):
        power[i, 16 + 4 * (1 + c), :] += np.linspace(0.05, 1.0, 16)  # a line whose level grows over time
    chain = ChainConfig(dynamic_range_db=40.0)
    deep = power_to_unit(torch.as_tensor(power), ChainConfig(dynamic_range_db=DEEP_FLOOR_DB)).numpy()
    per_frame = power_to_unit(torch.as_tensor(power), ChainConfig(dynamic_range_db=40.0, normalise="frame")).numpy()
    synth = finish_rows(deep, {}, 0, chain)
    steps = one_step_rows(deep, {}, 0, chain)
    assert set(steps) == {"linear power", "linear magnitude", "per-frame scaling",
                          "CA-CFAR (guard 4, training 8, 10 dB)", "threshold 0.2"}
    report = unpaired_gap(per_frame, labels, synth, labels, ["a", "b"], steps)
    for name in ("a", "b"):
        entry = report["classes"][name]
        assert entry["explained_by"] == "per-frame scaling" and entry["steps"]["per-frame scaling"] < 1e-3
        assert entry["mean_image_gap"] > 0.05
    same = unpaired_gap(synth, labels, synth, labels, ["a", "b"], steps)
    assert same["classes"]["a"]["explained_by"] is None
    md = write_unpaired_gap(per_frame, labels, synth, labels, ["a", "b"], tmp_path, steps)[1].read_text()
    assert "| a |" in md and "per-frame scaling" in md
