"""The data-efficiency curve: records grouped by rows per gesture and simulator, drawn and tabled."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from experiments.data_efficiency import curves, dirty_points, fitted_effects, markdown, plot, rwn_minus_model
from handradar.runs.tables import DIRTY_NOTE
from handradar.data.splits import few_shot_split
from tests.tasks.fakes import compose_train


def rec(k: int, seed: int, fit: str, **metrics: float) -> dict:
    params = {"task_name": "data_efficiency", "split.per_class": str(k), "seed": str(seed), "synth.fit_sim": fit}
    if fit != "none":
        params["synth.fitted.effects"] = "sync_offset" if k > 1 else "-"
    return {"params": params, "metrics": {f"test/acc_{m}": v for m, v in metrics.items()}}


RECORDS = [
    rec(1, 1, "effects", radar_only=0.2, model_synth=0.5, model_synth_only=0.4, radar_pool=0.7),
    rec(1, 2, "effects", radar_only=0.3, model_synth=0.6, model_synth_only=0.5, radar_pool=0.7),
    rec(4, 1, "effects", radar_only=0.4, model_synth=0.7, model_synth_only=0.6, radar_pool=0.7),
    rec(4, 1, "effects", enhanced_synth=0.75),  # RadarWeightNet's variant in a job of its own
    rec(4, 1, "none", model_synth_only=0.35),
    rec(1, 2, "none", model_synth_only=0.45),
    {"params": {"task_name": "few_shot_5pct", "split.fraction": "0.05"}, "metrics": {"test/acc_radar_only": 0.9}},
]


def test_curves_group_by_rows_and_simulator():
    got = curves(RECORDS)
    assert got["radar only"] == {1: [0.2, 0.3], 4: [0.4]}
    assert got["+ synthetic (fitted simulator)"] == {1: [0.5, 0.6], 4: [0.7]}
    assert got["synthetic only (fitted simulator)"] == {1: [0.4, 0.5], 4: [0.6]}
    assert got["+ synthetic (fitted simulator + RadarWeightNet)"] == {4: [0.75]}
    assert got["synthetic only (paper's simulator)"] == {0: [0.35, 0.45]}  # no real row involved
    assert got["real pool (ceiling)"] == {0: [0.7, 0.7]}  # one per seed, whatever k
    # an older run of the same point and seed (later in the list: records come latest first) is left out
    older = rec(1, 1, "effects", radar_only=0.9, model_synth=0.9)
    assert curves([*RECORDS, older])["radar only"] == {1: [0.2, 0.3], 4: [0.4]}
    assert fitted_effects([*RECORDS, older]) == fitted_effects(RECORDS)
    assert fitted_effects(RECORDS) == {1: ["seed 1: -", "seed 2: -"], 4: ["seed 1: sync_offset"]}
    # runs on recordings make a curve of their own, and leave the default world's alone
    mine = rec(1, 1, "effects", radar_only=0.1)
    mine["params"].update({"data.dataset._target_": "handradar.data.datasets.RecordingsFolder", "data.dataset.root": "/d/mine"})
    assert curves([mine, *RECORDS]) == curves(RECORDS)
    assert curves([mine, *RECORDS], "{recordings: mine}") == {"radar only": {1: [0.1]}}
    heldout = {**rec(1, 1, "effects", radar_only=0.3), "tags": {"handradar.world": "heldout"}}
    assert curves([heldout, *RECORDS]) == curves(RECORDS)
    assert curves([heldout], "{world: heldout}") == {"radar only": {1: [0.3]}}
    assert fitted_effects([mine, *RECORDS], data="{recordings: mine}") == {1: ["seed 1: -"]}


def test_fitted_values_come_from_the_jobs_fitted_simulator(tmp_path: Path):
    state = tmp_path / "data_efficiency" / "state" / "abc"
    state.mkdir(parents=True)
    (state / "fitted_sim.yaml").write_text("rcs_exponent: 0.25\neffects: [sync_offset]\n"
                                           "effect_params: {sync_offset: {offset_s: 0.02}}\n")
    (state / "fit_report.json").write_text('{"baseline": {"ssim": 0.91}, "after": {"ssim": 0.935}}')
    recs = [{**RECORDS[2], "tags": {"handradar.job_hash": "abc"}},
            {**RECORDS[0], "params": {**RECORDS[0]["params"], "synth.fitted.rcs_exponent": "0.1"}}]
    assert fitted_effects(recs, tmp_path) == {1: ["seed 1: e 0.1; -"],
                                              4: ["seed 1: e 0.25; sync_offset (offset_s 0.02); SSIM 0.910 -> 0.935"]}


def test_markdown_and_figure(tmp_path: Path):
    data = curves(RECORDS)
    md = markdown(data, fitted_effects(RECORDS))
    assert "| real rows per gesture | 0 | 1 | 4 |" in md
    assert "| radar only | – | 0.250 ± 0.071 (n=2) | 0.400 |" in md
    assert "| synthetic only (paper's simulator) | 0.400 ± 0.071 (n=2) | – | – |" in md
    assert "The real pool (ceiling), trained on the pool's real rows whatever k: 0.700 ± 0.000 (n=2)." in md
    assert DIRTY_NOTE not in md
    assert plot(data, tmp_path / "f.png").read_bytes()[:4] == b"\x89PNG"


def test_a_value_from_a_dirty_tree_is_marked():
    """The run that counts for a point and seed decides: a dirty run's values are marked, an older dirty run
    that a newer one replaced marks nothing."""
    dirty = {**rec(4, 3, "effects", radar_only=0.5, radar_pool=0.7), "provenance": {"commit": "abc1234.dirty"}}
    replaced = {**rec(1, 1, "effects", radar_only=0.9), "provenance": {"commit": "abc1234.dirty"}}
    records = [*RECORDS[:-1], dirty, replaced]
    assert dirty_points(records) == {("radar only", 4), ("real pool (ceiling)", 0)}
    md = markdown(curves(records), {}, dirty_at=dirty_points(records))
    assert "| radar only | – | 0.250 ± 0.071 (n=2) | 0.450 ± 0.071 (n=2) † |" in md
    assert "| + synthetic (fitted simulator) | – | 0.550 ± 0.071 (n=2) | 0.700 |" in md
    assert "whatever k: 0.700 ± 0.000 (n=3) †." in md and md.rstrip().endswith(DIRTY_NOTE)


def test_per_class_split_is_nested_and_exact():
    labels = np.repeat(np.arange(5), 20)
    prev = None
    for k in (1, 2, 4, 8):
        s = few_shot_split(labels, 0.05, seed=3, test="fixed", per_class=k)
        assert np.bincount(labels[s.train], minlength=5).tolist() == [k] * 5
        assert not np.intersect1d(s.train, s.test).size and len(s.pool) == 80
        if prev is not None:
            assert set(prev) <= set(s.train)
        prev = s.train
    with pytest.raises(ValueError, match="per_class must be at least 1"):
        few_shot_split(labels, 0.05, seed=3, test="fixed", per_class=0)


def test_preset_composes():
    cfg = compose_train(["+experiment=data_efficiency", "split.per_class=2"])
    assert cfg.task_name == "data_efficiency" and cfg.split.per_class == 2 and cfg.split.test == "fixed"
    assert list(cfg.variants) == ["radar_only", "model_synth", "model_synth_only"]  # the pool: once per seed


def test_radarweightnet_minus_model_is_paired_by_seed_and_flags_harm():
    records = [rec(4, 1, "effects", enhanced_synth=0.60), rec(4, 2, "effects", enhanced_synth=0.80),
               rec(4, 1, "effects", model_synth=0.70), rec(4, 2, "effects", model_synth=0.70),
               rec(4, 3, "effects", model_synth=0.70),  # no RadarWeightNet run of seed 3: not paired
               rec(4, 1, "none", enhanced_synth=0.10)]  # the paper's simulator: not on the curve
    diffs = rwn_minus_model(records)
    assert list(diffs) == [4] and diffs[4] == pytest.approx({"1": -0.10, "2": +0.10})
    md = markdown(curves(records), {}, diffs)
    assert "| RadarWeightNet minus model-based, per seed | s1 -0.100, s2 +0.100 |" in md
    # seed spreads: RadarWeightNet 0.141, model-based 0.000: -0.100 is within the larger one
    assert "RadarWeightNet below model-based by more than the larger seed spread at: no size." in md
    tight = [rec(4, 1, "effects", enhanced_synth=0.60), rec(4, 2, "effects", enhanced_synth=0.62),
             rec(4, 1, "effects", model_synth=0.70), rec(4, 2, "effects", model_synth=0.71)]
    md = markdown(curves(tight), {}, rwn_minus_model(tight))
    assert "at: 4 (-0.100 against a spread of 0.014)." in md
    # one seed on both curves: no spread, so not judged (and not reported as harmless)
    single = tight[::2]
    assert "at: no size. Too few seeds to judge at: 4." in markdown(curves(single), {}, rwn_minus_model(single))
    # another synthesis setting (several draws per skeleton) never enters the curve
    drawn = rec(4, 1, "effects", model_synth=0.99)
    drawn["params"]["synth.samples_per_row"] = "2"
    assert curves([drawn, *tight])["+ synthetic (fitted simulator)"] == {4: [0.70, 0.71]}
