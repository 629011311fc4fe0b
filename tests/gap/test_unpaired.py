"""The unpaired gap report (handradar.gap.unpaired): its statistics against closed forms, and its ranking."""

from __future__ import annotations

import json

import numpy as np
import pytest

from handradar.gap.unpaired import (
    cohen_d,
    doppler_centroid,
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
    with pytest.raises(ValueError, match="class 'c' has 20 measured and 0 synthetic rows"):
        unpaired_gap(real, labels, synth[:40], labels[:40], ["a", "b", "c"])
