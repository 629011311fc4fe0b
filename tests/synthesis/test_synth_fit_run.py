"""The synth_fit job (train.py +experiment=synth_fit) end to end on 12 tiny rows: metrics of every
fit the data can form, the network file and the three figures.

The "measured" rows are the paper's simulator itself, so the modelling-only scores are known without
the job: SSIM 1 and MSE 0 on every test split. A job that paired a test row with another row's
measurement, or scored another simulator, would miss them."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from omegaconf import OmegaConf
from PIL import Image

import tests.tasks.test_closed_loop as closed_loop
from handradar.synthesis.fit import load_weight_net
from handradar.tasks.train import run
from tests.tasks.fakes import compose_train


def test_synth_fit_scores_every_split_and_draws_its_figures(radar, short_chain, tmp_path: Path, monkeypatch):
    monkeypatch.setattr(closed_loop, "TRUTH", {})  # measured = the paper's simulator, no effect
    data = closed_loop._measured(tmp_path / "measured.h5", radar, short_chain, per_class=4)
    cfg = compose_train([
        "+experiment=synth_fit", "data=hdf5", f"data.path={data}", f"paths.log_dir={tmp_path}/logs",
        f"paths.cache_dir={tmp_path}/cache", "logger=none", "print_table=false", "checkpoint_interval_s=0",
        "skeleton_rate_hz=100.0", "synth_fit.max_train_rows=8", "synth_fit.max_test_rows=4", "synth_fit.n_jobs=1",
        "synth_fit.phases=[{epochs: 1, lr: 1.0e-3, batch_size: 4}]", "synth_fit.net.hidden=16", "synth_fit.net.fc=[16,8]"])
    run_dir = run(cfg, tmp_path / "run")
    metrics = OmegaConf.to_container(OmegaConf.load(run_dir / "metrics.json"))
    # subjects s0-s2 (row i % 3), one- and two-hand rows, every angle 0, no occlusion: the in-distribution
    # fit, one-hand -> two-hand and unseen subjects can be formed; angle and occlusion cannot
    suffixes = ["", "_hands", "_subject"]
    assert set(metrics) == {f"test/{m}_{k}{s}" for m in ("ssim", "mse") for k in ("model", "enhanced") for s in suffixes}
    for s in suffixes:
        assert metrics[f"test/ssim_model{s}"] == pytest.approx(1.0, abs=1e-5)
        assert metrics[f"test/mse_model{s}"] == pytest.approx(0.0, abs=1e-6)
        assert -1.0 <= metrics[f"test/ssim_enhanced{s}"] <= 1.0 and metrics[f"test/mse_enhanced{s}"] >= 0.0
    net, _ = load_weight_net(run_dir / "radarweightnet.pt")
    assert sum(p.numel() for p in net.parameters()) > 0 and all(torch.isfinite(p).all() for p in net.parameters())
    for name in ("measured_model_enhanced", "reflection_point_decomposition", "learned_weights"):
        with Image.open(run_dir / "figures" / f"{name}.png") as im:
            assert im.format == "PNG" and min(im.size) > 100
    fits = sorted(p.name for p in Path(cfg.state_dir).rglob("synth_fit_*") if p.is_dir())
    assert fits == ["synth_fit_hands", "synth_fit_main", "synth_fit_subject"]
