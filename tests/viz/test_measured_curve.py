"""The measured curve figure (handradar.viz.measured.plot_measured_curve) from the measured table's rows."""

from __future__ import annotations

import numpy as np

from handradar.runs.tables import build_tables
from handradar.viz.measured import plot_measured_curve


def record(k: str, seed: int, acc: float, variant: str = "radar_only") -> dict:
    params = {"data.dataset._target_": "handradar.data.measured.MeasuredDataset", "data.dataset.manifest": "m/x.yaml",
              "measured.per_class": k, "seed": str(seed), "job": "handradar.tasks.measured.run_measured",
              "measured.variants": variant, "measured.tests": "A,B", "measured.setting": "s"}
    return {"params": params, "metrics": {f"test/acc_{variant}_A": acc, f"test/acc_{variant}_B": acc + 0.1}}


def test_curve_from_the_measured_table(tmp_path):
    records = [record("1", 1, 0.3), record("1", 2, 0.4), record("all", 1, 0.6), record("0", 1, 0.2, "model_synth_only")]
    table = next(t for t in build_tables(records) if t.name == "measured")
    assert table.rows["1 per class, A {measured: x}"]["Radar only"] == [0.3, 0.4]
    out = plot_measured_curve(table.rows, tmp_path / "curve.png", anchors={"A": 0.67})
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    import matplotlib.image as mpimg

    assert mpimg.imread(out).shape[1] > 2 * mpimg.imread(out).shape[0] * 0.9 and np.isfinite(mpimg.imread(out)).all()
