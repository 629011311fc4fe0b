"""The diagnosis on small reference-world data (not data the simulator made): a withheld sync offset
is the leading candidate with a gap_closed whose CI excludes 0, and the effect-free world of the same
subjects gets no false cause."""

from __future__ import annotations

import pytest
from hydra import compose, initialize_config_dir

from handradar.config import VERSION_BASE, config_dir
from handradar.gap.benchmark import Case, case_world
from handradar.gap.data import load_dataset
from handradar.gap.diagnosis import diagnose
from handradar.sim.factory import SimFactory
from handradar.world import build_world_dataset

# 4 gestures x 2 subjects x 2 angles x 2 repetitions = 32 rows (16 evaluation rows)
SMALL = {"gestures": ["grasp", "circle", "slide", "finger_wave"], "subjects": 2, "angles_deg": [0.0, 30.0],
         "repetitions": 2, "workers": 1}
CANDIDATES = ["sync_offset", "tracking_jitter", "palm"]


def _diagnose(case: Case, radar, chain, cache, world: dict = SMALL, **settings):
    path = build_world_dataset(case_world(world, case), radar, chain, cache / "world", progress=False)
    data = load_dataset(path)
    with initialize_config_dir(str(config_dir()), version_base=VERSION_BASE):
        sim = compose("diagnose", overrides=["data.root=/unused"]).sim  # the paper's simulator, as diagnose.py has it
    factory = SimFactory.from_config(sim, data.radar, data.chain, skeleton_rate_hz=data.skeleton_rate_hz)
    cfg = {"candidates": CANDIDATES, "radarweightnet": False, "fit_rows": None, "n_boot": 500, "greedy_max": 1, **settings}
    return diagnose(data, factory, {}, cfg, cache_dir=cache / "gap", progress=False).report


# 4 gestures x 2 subjects x 2 repetitions on boresight = 16 rows of 6-frame captures, 4-frame windows
TINY = {**SMALL, "angles_deg": [0.0], "capture_frames": 6, "seed": 1}


def test_reference_world_sync_offset_leads_on_tiny_data(radar, short_chain, tmp_path):
    """The fast version of the test below on 16 rows (8 evaluation rows). Measured, world seeds 0-2:
    sync_offset leads by gap_closed (+0.15, +0.23, +0.36; runner-up at most +0.05), verdict
    inconclusive or sync_offset; on the effect-free world none or inconclusive, and sync_offset there
    makes things worse (-0.30, -0.50, -0.65): it is not a generic closer."""
    rep = _diagnose(Case("sync_offset", ("sync_offset",), "sync_offset"), radar, short_chain, tmp_path, TINY,
                    n_boot=300, rcs_exponents=[1.0, 0.5], folds=1)
    assert rep["n_calibration"] + rep["n_evaluation"] == 16 and rep["baseline"]["ssim"] < 0.9  # a real gap
    top, runner_up = sorted(rep["candidates"], key=lambda c: -c["gap_closed"])[:2]
    assert top["effect"] == "sync_offset" and top["gap_closed"] > 0.1 > runner_up["gap_closed"], rep["candidates"]
    assert rep["cause"] in ("sync_offset", "inconclusive")
    clean = _diagnose(Case("nothing", (), "none"), radar, short_chain, tmp_path, TINY, n_boot=300,
                      rcs_exponents=[1.0, 0.5], folds=1)
    assert clean["cause"] in ("none", "inconclusive"), clean["candidates"]
    assert next(c for c in clean["candidates"] if c["effect"] == "sync_offset")["gap_closed"] < 0


@pytest.mark.slow
def test_reference_world_sync_offset_leads_and_the_clean_world_has_no_cause(radar, chain, tmp_path):
    rep = _diagnose(Case("sync_offset", ("sync_offset",), "sync_offset"), radar, chain, tmp_path)
    top = max(rep["candidates"], key=lambda c: c["gap_closed"])
    assert top["effect"] == "sync_offset" and top["ci95"][0] > 0.0, rep["candidates"]
    assert rep["cause"] in ("sync_offset", "inconclusive")  # 16 evaluation rows may not separate it
    clean = _diagnose(Case("nothing", (), "none"), radar, chain, tmp_path)
    assert clean["cause"] in ("none", "inconclusive"), clean["candidates"]
