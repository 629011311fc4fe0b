"""The closed loop of train.py: diagnose the real training rows -> fitted simulator -> synthesis.

The "measured" rows are the simulator's own, with a skeleton smoothing (tracking_jitter) against
jitter added to the stored skeletons and a radar/skeleton sync offset: the paper's simulator lacks
both. The job must recover both from the real training rows alone, and a classifier trained on
its synthetic spectrograms alone must recognise the measured test rows.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from handradar.data.hdf5 import open_writer
from handradar.gap.data import GapData
from handradar.gap.job import fit_simulator
from handradar.sim.factory import SimFactory
from handradar.tasks.train import nuisance_draw, run
from tests.gap.conftest import rows
from tests.sim.demo import window
from tests.tasks.fakes import compose_train

RATE = 100.0
TRUTH = {"sync_offset": {"offset_s": 0.05}, "tracking_jitter": {"sigma_s": 0.02}}
CLASSES = ["small", "wide", "two_hands"]


def _measured(path: Path, radar, chain, per_class: int, classes: list[str] = CLASSES) -> Path:
    """``per_class`` rows of each of ``classes``; class c moves as motion c mod 3."""
    n_steps = int(round(chain.frames_per_window(radar) * radar.frame_period_s * RATE))
    times = np.arange(n_steps) / RATE
    rng = np.random.default_rng(0)
    sk, masks, labels = [], [], []
    for i in range(per_class * len(classes)):
        c = i % len(classes)
        # three motions: fingers barely flexing, a wide flex while the hand approaches, two hands
        p, m = window(times, hands=2 if c % 3 == 2 else 1, seed=i, amplitude_rad=(0.15, 1.0, 0.5)[c % 3],
                      drift_m_s=(0.0, 0.0, -0.15 if c % 3 == 1 else 0.0),
                      centre=(rng.uniform(-0.05, 0.05), -0.06, rng.uniform(0.25, 0.35)))
        # tracker jitter on the stored skeleton: 2 mm, independent per step
        sk.append(p + rng.normal(0.0, 0.002, p.shape).astype(np.float32) * m[..., None, None])
        masks.append(m)
        labels.append(c)
    skel, mask = np.stack(sk), np.stack(masks)
    sim = SimFactory(radar, chain, skeleton_rate_hz=RATE)(TRUTH)
    with torch.no_grad():
        spec = sim(torch.as_tensor(skel), torch.as_tensor(mask)).numpy()
    with open_writer(path, classes=classes, radar=radar, chain=chain, skeleton_rate_hz=RATE, n_steps=n_steps,
                     config_hash="closed-loop-test") as w:
        for i, c in enumerate(labels):
            w.append(spec[i], c, skel[i], mask[i], 0.0,
                     {"gesture": classes[c], "subject": f"s{i % 3}", "angle_deg": 0.0, "hands": 2 if c % 3 == 2 else 1,
                      "occlusion": False, "repetition": i, "recording": f"r{i}"})
    return path


def _job(preset: str, data: Path, tmp_path: Path, *, variant: str, steps: int, candidates: str, n_boot: int,
         split: tuple[str, ...]):
    """A train.py job on the measured rows with a tiny CNN, its simulator fitted on ``candidates``."""
    return compose_train([
        f"+experiment={preset}", "data=hdf5", f"data.path={data}", f"paths.log_dir={tmp_path}/logs",
        f"paths.cache_dir={tmp_path}/cache", "logger=none", "print_table=false", "checkpoint_interval_s=0",
        "skeleton_rate_hz=100.0", *split, f"variants=[{variant}]", "model.net._target_=tests.tasks.fakes.tiny_cnn",
        "~model.net.stem_stride", f"trainer.max_steps={steps}", "trainer.enable_progress_bar=false",
        "synth.fit_sim=effects", f"+synth.fit.candidates=[{candidates}]", "+synth.fit.rcs_exponents=[1.0]",
        f"synth.fit.n_boot={n_boot}"])


FULL_SPLIT = ("split.fraction=1.0", "split.test_fraction=0.25")


@pytest.mark.slow
def test_fitted_simulator_recovers_smoothing_and_offset_and_synthetic_only_learns(radar, chain, tmp_path: Path):
    data = _measured(tmp_path / "measured.h5", radar, chain, per_class=16)
    cfg = _job("few_shot_5pct", data, tmp_path, variant="model_synth_only", steps=150,
               candidates="sync_offset,tracking_jitter,noise", n_boot=300, split=FULL_SPLIT)
    run_dir = run(cfg, tmp_path / "run")
    state = next((tmp_path / "logs").rglob("fitted_sim.yaml"))
    fitted = OmegaConf.to_container(OmegaConf.load(state))
    assert set(fitted["effects"]) >= {"sync_offset", "tracking_jitter"}
    assert fitted["effect_params"]["sync_offset"]["offset_s"] == pytest.approx(0.05, abs=1e-6)
    assert fitted["effect_params"]["tracking_jitter"]["sigma_s"] == pytest.approx(0.02, abs=1e-6)
    metrics = OmegaConf.to_container(OmegaConf.load(run_dir / "metrics.json"))
    assert metrics["test/acc_model_synth_only"] >= 0.6  # 3 classes, 12 test rows: chance 0.33


def test_closed_loop_through_train_fast(radar, short_chain, tmp_path: Path):
    """The fast version of the test above: 24 rows of 4-frame windows, 10 training steps. The fit
    sees the 18 training rows only (9 + 9 in its own split), never the 6 test rows, and recovers both
    missing settings exactly (measured; with 12 rows it picks tracking_jitter alone at 0.04 s)."""
    data = _measured(tmp_path / "measured.h5", radar, short_chain, per_class=8)
    cfg = _job("few_shot_5pct", data, tmp_path, variant="model_synth_only", steps=10,
               candidates="sync_offset,tracking_jitter", n_boot=200, split=FULL_SPLIT)
    run_dir = run(cfg, tmp_path / "run")
    state = next((tmp_path / "logs").rglob("fitted_sim.yaml")).parent
    fitted = OmegaConf.to_container(OmegaConf.load(state / "fitted_sim.yaml"))
    assert set(fitted["effects"]) == {"sync_offset", "tracking_jitter"}
    assert fitted["effect_params"]["sync_offset"]["offset_s"] == pytest.approx(0.05, abs=1e-6)
    assert fitted["effect_params"]["tracking_jitter"]["sigma_s"] == pytest.approx(0.02, abs=1e-6)
    split = np.load(state / "split.npz")
    assert len(split["test"]) == 6 and not np.intersect1d(split["train"], split["test"]).size
    report = json.loads((state / "fit_report.json").read_text())
    assert report["n_calibration"] + report["n_evaluation"] == len(split["train"]) == 18
    metrics = OmegaConf.to_container(OmegaConf.load(run_dir / "metrics.json"))
    assert set(metrics) == {"test/acc_model_synth_only"} and 0.0 <= metrics["test/acc_model_synth_only"] <= 1.0


def _one_row_job(data: Path, tmp_path: Path):
    return _job("data_efficiency", data, tmp_path, variant="model_synth", steps=5, candidates="sync_offset", n_boot=100,
                split=("split.per_class=1", "split.test_fraction=0.34"))


def test_one_row_per_gesture_fits(radar, short_chain, tmp_path: Path):
    """One training row of each of 6 gestures: the closed loop fits on all 6 (one calibration/evaluation split)."""
    classes = [f"{c}{k}" for k in (1, 2) for c in CLASSES]
    data = _measured(tmp_path / "measured.h5", radar, short_chain, per_class=3, classes=classes)
    run_dir = run(_one_row_job(data, tmp_path), tmp_path / "run")
    state = next((tmp_path / "logs").rglob("fit_report.json")).parent
    report = json.loads((state / "fit_report.json").read_text())
    split = np.load(state / "split.npz")
    assert sorted(split["train"] % 6) == list(range(6)) and not np.intersect1d(split["train"], split["test"]).size
    assert report["n_calibration"] + report["n_evaluation"] == 6
    assert set(OmegaConf.to_container(OmegaConf.load(run_dir / "metrics.json"))) == {"test/acc_model_synth"}


def test_too_few_rows_to_fit_say_so(radar, short_chain, tmp_path: Path):
    from handradar.errors import TooFewRows

    data = _measured(tmp_path / "measured.h5", radar, short_chain, per_class=3)  # 3 gestures x 1 training row
    with pytest.raises(TooFewRows, match=r"fits the simulator on the split's 3 training rows .*synth.fit_sim=none"):
        run(_one_row_job(data, tmp_path), tmp_path / "run")


@pytest.mark.parametrize("exponent", [1.0, 0.5])
def test_calibration_only_fit_keeps_no_effect(radar, short_chain, exponent):
    """synth.fit_sim=calibrate: step 0 alone; the fitted simulator has the calibrated exponent (the one
    the rows were made with, either end of the grid, under an antenna pattern the baseline lacks:
    measured SSIM 0.966 vs 0.895 at 1.0, 0.969 vs 0.921 at 0.5) and no effect, though one is there."""
    rs, labels, meta = rows(radar, short_chain, 16, seed=0)
    sim = SimFactory(radar, short_chain, rcs_exponent=exponent)({"antenna_pattern": {"q": 8.0}})
    with torch.no_grad():
        measured = sim(torch.as_tensor(rs.skeletons), torch.as_tensor(rs.masks), times=torch.as_tensor(rs.times))
    data = GapData(measured.numpy(), rs, labels, meta, radar, short_chain, 100.0)
    diag, settings = fit_simulator(data, {"rcs_exponent": 1.0}, {"rcs_exponents": [1.0, 0.5], "radarweightnet": False,
                                                                  "n_boot": 200}, effects=False)
    assert settings["effects"] == [] and diag.report["candidates"] == []
    assert settings["rcs_exponent"] == exponent and diag.report["cause"] == "none"


def test_nuisance_draws_stay_within_bounds_and_leave_absent_effects_alone():
    sim = {"rcs_exponent": 0.9, "effects": ["noise"], "effect_params": {"noise": {"snr_db": 20.0}}}
    spread = {"rcs_exponent": 0.5, "noise": {"snr_db": 3.0}, "antenna_pattern": {"q": 1.0}}
    draws = [nuisance_draw(sim, spread, np.random.default_rng(k)) for k in range(200)]
    rcs = np.array([d["rcs_exponent"] for d in draws])
    snr = np.array([d["effect_params"]["noise"]["snr_db"] for d in draws])
    assert 0.0 <= rcs.min() and rcs.max() <= 1.0 and (rcs == 1.0).any()  # clipped at the bound
    assert abs(snr.mean() - 20.0) < 0.6 and 2.5 < snr.std() < 3.5
    assert all("antenna_pattern" not in d["effect_params"] for d in draws)
    assert sim["effect_params"]["noise"]["snr_db"] == 20.0  # the fitted settings are not mutated
    with pytest.raises(ValueError, match="effect's parameter"):
        nuisance_draw(sim, {"noise": {"level": 1.0}}, np.random.default_rng(0))


def test_fitted_sim_and_randomisation_compose(tmp_path: Path):
    cfg = compose_train(["+experiment=few_shot_5pct", "synth.fit_sim=effects", "synth.samples_per_row=3",
                         "+synth.randomize.rcs_exponent=0.1", "+synth.randomize.noise.snr_db=2.5"])
    assert cfg.synth.fit_sim == "effects" and cfg.synth.samples_per_row == 3
    assert cfg.synth.randomize.noise.snr_db == 2.5
