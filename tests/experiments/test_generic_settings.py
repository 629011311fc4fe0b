"""experiments.generic_settings: a record's table and the summary over records (the judging runs are experiments)."""

from __future__ import annotations

import json
from pathlib import Path

from experiments.generic_settings import markdown, summary_markdown


def _record(coherence_ci: list[float]) -> dict:
    cal = {"rcs_exponent": 0.5, "folds": [{"rcs_exponent": 0.5, "coherence": 0.5}, {"rcs_exponent": 1.0, "coherence": 0.0}]}
    return {"rows": 240, "exponents_only": {"ssim": 0.9375, "calibration": {}},
            "settings": {"bone_extents": {"values": [0.0, 1.0], "ssim": 0.9375, "gap_closed": 0.0, "ci95": [0.0, 0.0],
                                          "helps": False, "calibration": {"folds": [{"bone_extent": 0.0}] * 2}},
                         "coherences": {"values": [1.0, 0.5, 0.0], "ssim": 0.944, "gap_closed": 0.1046,
                                        "ci95": coherence_ci, "helps": coherence_ci[0] > 0, "calibration": cal}}}


def test_record_table_names_each_folds_pick_and_the_verdict():
    md = markdown(_record([0.083, 0.127]))
    assert "| `diagnose.coherences` | [1.0, 0.5, 0.0] | 0.9440 | +0.1046 [+0.0830, +0.1270] | 0.5, 0 | yes |" in md
    assert "| `diagnose.bone_extents` | [0.0, 1.0] | 0.9375 | +0.0000 [+0.0000, +0.0000] | 0, 0 | no |" in md


def test_summary_has_one_row_per_world_and_size(tmp_path: Path):
    (tmp_path / "scatterers_240.json").write_text(json.dumps(_record([0.083, 0.127])))
    (tmp_path / "default_36.json").write_text(json.dumps(_record([-0.01, 0.2])))
    rows = summary_markdown(tmp_path).splitlines()
    assert rows[0] == "| world, recordings | exponents alone: SSIM | `bone_extents` | `coherences` |"
    assert rows[2] == "| default, 36 | 0.9375 | +0.000 [+0.000, +0.000] | +0.105 [-0.010, +0.200] |"
    assert rows[3].endswith("| +0.105 [+0.083, +0.127] **helps** |")
