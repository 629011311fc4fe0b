"""Hybrid synthesis end to end: RadarWeightNet fitted to "measured" spectrograms through the
simulator and the chain beats the modelling-only simulator on held-out rows; the providers and
handradar-synth write valid datasets."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch

from handradar.data.hdf5 import open_writer, read_attrs, validate
from handradar.hand.model import HandModelConfig
from handradar.hand.skeleton import N_BONES
from handradar.sim.simulator import Simulator
from handradar.synthesis.fit import (
    Phase,
    Shrunk,
    choose_shrink,
    fit_weight_net,
    guarded_weight_net,
    load_pairs,
    load_weight_net,
    predict,
    predict_cached,
    save_weight_net,
    synth_scores,
)
from handradar.synthesis.providers import (
    cache_rows,
    motion_window,
    spectrograms_of,
    synthesize_rows,
)
from tests.sim.demo import window

RATE = 100.0
HAND = HandModelConfig(visibility_stride=4)


def _bone_gains() -> torch.Tensor:
    """The "real" radar's hidden per-bone gains: fingertips strong, metacarpals weak (slot weights)."""
    g = torch.ones(2 * N_BONES)
    for k in range(2 * N_BONES):
        b = k % N_BONES
        g[k] = 3.0 if b in (2, 6, 10, 14, 18) else (0.2 if b in (3, 7, 11, 15) else 1.0)
    return g


def make_measured(path: Path, radar, chain, n: int, seed: int = 0) -> Path:
    """A dataset whose "measurements" are the simulator with fixed per-bone gains the plain model lacks."""
    sim = Simulator(radar, chain, hand=HAND, skeleton_rate_hz=RATE)
    n_steps = int(round(chain.frames_per_window(radar) * radar.frame_period_s * RATE))
    times = np.arange(n_steps) / RATE
    labels = np.arange(n) % 2
    skel, mask = zip(*[window(times, seed=seed + i, amplitude_rad=0.3 + 0.4 * (labels[i] == 1)) for i in range(n)])
    skel, mask = torch.as_tensor(np.stack(skel)), torch.as_tensor(np.stack(mask))
    gains = _bone_gains()[None, None].expand(n, n_steps, -1)
    with torch.no_grad():
        spec = sim(skel, mask, weights=gains).numpy()
    with open_writer(path, classes=["slow", "wide"], radar=radar, chain=chain, skeleton_rate_hz=RATE, n_steps=n_steps,
                     config_hash="test") as w:
        for i in range(n):
            w.append(spec[i], int(labels[i]), skel[i].numpy(), mask[i].numpy(), 0.0,
                     {"gesture": ["slow", "wide"][labels[i]], "subject": f"s{i % 3}", "angle_deg": 0.0, "hands": 1,
                      "occlusion": False, "repetition": i, "recording": f"r{i}"})
    return path


@pytest.fixture(scope="module")
def measured(tmp_path_factory, radar, short_chain) -> Path:
    torch.set_num_threads(1)
    return make_measured(tmp_path_factory.mktemp("synth") / "measured.h5", radar, short_chain, n=16)


def test_weight_net_learns_what_the_model_lacks(measured, radar, short_chain, tmp_path):
    """Learning tested by learning: fitted on 10 rows, the enhanced simulator is closer (SSIM, MSE)
    to held-out measurements than the modelling-only one, which misses the per-bone gains."""
    sim = Simulator(radar, short_chain, hand=HAND, skeleton_rate_hz=RATE)
    rows = np.arange(16)
    caches = cache_rows(measured, rows, sim, tmp_path / "cache", n_jobs=1)
    targets = spectrograms_of(measured, rows)
    train, test = load_pairs(caches, targets, rows[:10]), load_pairs(caches, targets, rows[10:])
    before = synth_scores(sim, fit_weight_net(sim, train, phases=[Phase(0, 1e-3, 8)]), test)
    net = fit_weight_net(sim, train, phases=[Phase(25, 3e-3, 5), Phase(10, 1e-3, 5)], seed=0,
                         net_kwargs={"hidden": 32, "fc": (32, 32)})
    after = synth_scores(sim, net, test)
    assert before["ssim_enhanced"] == pytest.approx(before["ssim_model"], abs=0.01)  # starts at the plain model
    assert after["ssim_enhanced"] > after["ssim_model"] + 0.02
    assert after["mse_enhanced"] < after["mse_model"]
    # streamed from the float16 cache in batches: the in-memory (unpacked) prediction
    streamed = predict_cached(sim, net, caches, rows[10:], batch_size=4)
    assert float((streamed - predict(sim, net, test)).abs().max()) < 1e-3
    # the checkpoint round-trips
    f = save_weight_net(tmp_path / "rwn.pt", net, sim, {"hidden": 32, "fc": (32, 32)})
    net2, info = load_weight_net(f)
    assert info["skeleton_rate_hz"] == RATE
    assert synth_scores(sim, net2, test) == pytest.approx(after)


def test_guarded_weight_net_keeps_what_helps_held_out_and_shrinks_what_does_not(measured, radar, short_chain,
                                                                              tmp_path):
    """Where the measurements carry per-bone gains the plain model lacks, held-out rows show the
    network's gain and it is kept (shrink > 0); where the measurement is the plain model itself, nothing
    is left to learn, held-out SSIM cannot improve and the network is shrunk to weight 1 (the model)."""
    sim = Simulator(radar, short_chain, hand=HAND, skeleton_rate_hz=RATE)
    rows = np.arange(12)
    caches = cache_rows(measured, rows, sim, tmp_path / "cache", n_jobs=1)
    with h5py.File(measured) as h5:
        labels = h5["labels"][()][rows]
    kw = {"phases": [Phase(25, 3e-3, 4), Phase(10, 1e-3, 4)], "net_kwargs": {"hidden": 32, "fc": (32, 32)},
          "n_boot": 300}
    gains = load_pairs(caches, spectrograms_of(measured, rows), rows)
    net, report = guarded_weight_net(sim, gains, labels, folds=2, **kw)
    assert report["shrink"] > 0 and report["gain_ci95"][0] > 0, report
    assert report["heldout_ssim"][str(report["shrink"])] > report["heldout_ssim"]["0.0"]
    plain = load_pairs(caches, predict(sim, None, gains).numpy(), rows)  # measured = the model itself
    net, report = guarded_weight_net(sim, plain, labels, folds=2, **kw)
    assert report["shrink"] == 0.0 and report["gain"] <= 0.0, report
    torch.testing.assert_close(predict(sim, net, plain), predict(sim, None, plain), atol=1e-5, rtol=0)
    with pytest.raises(ValueError, match="shrink"):
        Shrunk(net.net, 1.5)


def test_choose_shrink_keeps_the_best_shrink_only_when_its_heldout_gain_clears_zero():
    """Closed-form rows: a gain every row shares is kept; the same mean gain made of large gains and
    losses that cancel (its bootstrap CI spans 0) falls back to shrink 0, the modelling-only simulator."""
    model = np.full(40, 0.5)
    steady = {0.0: model, 0.5: np.full(40, 0.55), 1.0: np.full(40, 0.6)}
    shrink, report = choose_shrink(model, steady, n_boot=500)
    assert shrink == 1.0 and report["shrink_best_ssim"] == 1.0
    assert report["gain"] == pytest.approx(0.2) and report["gain_chosen_ci95"][0] > 0
    noisy = {0.0: model, 0.5: model + 0.0005, 1.0: np.tile([0.79, 0.23], 20)}  # mean 0.51: gain 0.02
    shrink, report = choose_shrink(model, noisy, n_boot=500)
    assert report["shrink_best_ssim"] == 1.0 and report["gain_chosen_ci95"][0] < 0 < report["gain_chosen_ci95"][1]
    assert shrink == 0.0 and report["shrink"] == 0.0
    worse = {0.0: model, 1.0: np.full(40, 0.4)}
    assert choose_shrink(model, worse, n_boot=500)[0] == 0.0


def test_fit_is_reproducible_and_resumable(measured, radar, short_chain, tmp_path):
    sim = Simulator(radar, short_chain, hand=HAND, skeleton_rate_hz=RATE)
    caches = cache_rows(measured, np.arange(6), sim, tmp_path / "cache", n_jobs=1)
    train = load_pairs(caches, spectrograms_of(measured, np.arange(6)), np.arange(6))
    phases = [Phase(2, 1e-3, 3), Phase(2, 5e-4, 2)]
    kw = {"hidden": 16, "fc": (16, 16)}
    a = fit_weight_net(sim, train, phases=phases, seed=3, net_kwargs=kw)
    b = fit_weight_net(sim, train, phases=phases, seed=3, net_kwargs=kw, ckpt_dir=tmp_path / "ck")
    for pa, pb in zip(a.state_dict().values(), b.state_dict().values()):
        torch.testing.assert_close(pa, pb, rtol=0, atol=0)
    assert (tmp_path / "ck" / "last.ckpt").is_file()  # written at the start of each later epoch


def test_providers_follow_the_contract(measured, radar, short_chain, tmp_path):
    from handradar.synthesis.providers import load_synthetic

    labels = read_attrs(measured)["n"]
    rows = np.array([3, 1, 7, 12])
    with h5py.File(measured) as h5:
        y = h5["labels"][()][rows]
    for mode in ("model", "enhanced"):
        out = synthesize_rows(measured, rows, mode, fit_rows=np.arange(8), seed=0, cache_dir=tmp_path,
                              phases=[Phase(2, 1e-3, 4)], net_kwargs={"hidden": 16, "fc": (16, 16)}, n_jobs=1,
                              sim={"hand": HAND})
        validate(out)
        data = load_synthetic(out, y, shape=(64, 8))
        assert data.x.shape == (4, 64, 8) and labels == 16
        assert list(data.meta["recording"]) == [f"r{r}" for r in rows]
        again = synthesize_rows(measured, rows, mode, fit_rows=np.arange(8), seed=0, cache_dir=tmp_path,
                                phases=[Phase(2, 1e-3, 4)], net_kwargs={"hidden": 16, "fc": (16, 16)}, n_jobs=1,
                                sim={"hand": HAND})
        assert again == out  # cached
    guarded = synthesize_rows(measured, rows, "enhanced", fit_rows=np.arange(8), seed=0, cache_dir=tmp_path,
                              phases=[Phase(2, 1e-3, 4)], net_kwargs={"hidden": 16, "fc": (16, 16)}, n_jobs=1,
                              sim={"hand": HAND}, guard_folds=2)
    assert guarded != out  # another key
    with h5py.File(guarded) as h5:
        report = json.loads(h5.attrs["rwn_guard"])
    assert report["folds"] == 2 and report["rows"] == 8 and report["shrink"] in (0.0, 0.25, 0.5, 0.75, 1.0)


def test_motion_window_picks_the_gesture():
    from handradar.hand.skeleton import HandSequence

    t = np.arange(0, 4.0, 0.05)  # 20 fps, 4 s: still, then 1 s of motion at 2..3 s
    pos, mask = window(t, seed=1)
    still = pos[0].copy()
    moving = (t >= 2.0) & (t < 3.0)
    pos[~moving] = still
    seq = HandSequence(pos, t, mask)
    w = motion_window(seq, 160, 100.0)  # 1.6 s window
    assert w.positions.shape == (160, 2, 21, 3) and w.times[0] == 0
    speed = np.linalg.norm(np.diff(w.positions, axis=0), axis=-1).sum(axis=(1, 2))
    assert speed.sum() >= 0.95 * np.linalg.norm(np.diff(pos, axis=0), axis=-1).sum()  # all the motion is inside
    short = HandSequence(pos[:10], t[:10], mask[:10])  # 0.45 s: centred, ends held
    ws = motion_window(short, 160, 100.0)
    np.testing.assert_allclose(ws.positions[0], pos[0], atol=1e-6)
    np.testing.assert_allclose(ws.positions[-1], pos[9], atol=1e-6)


def test_motions_source_config():
    """conf/source/motions.yaml: the motion library's eight default classes, read from no folder."""
    from hydra import compose, initialize_config_dir

    from handradar.config import config_dir
    from handradar.data.skeletons import iter_source, source_classes
    from handradar.synthesis.providers import source_options

    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        cfg = compose("synth", overrides=["source=motions", "out=x.h5"])
    name, root, options = source_options(cfg.source)
    classes = ("push", "pull", "swipe_left", "swipe_right", "tap", "pinch", "circle", "idle")
    assert (name, root, options["per_class"], options["seed"], options["duration_s"]) == ("motions", "", 50, 0, 3.2)
    assert source_classes(name, classes=options["classes"]) == classes
    items = list(iter_source(name, root, **{**options, "per_class": 2}))
    assert [(it.label, it.meta["motion"]) for it in items[12:14]] == [(6, "circle_cw"), (6, "circle_ccw")]
    assert [it.name for it in items[::2]] == [f"{c}/0" for c in classes]
    assert all(it.sequence.times[-1] == pytest.approx(3.2, abs=0.011) for it in items)


def test_handradar_synth_on_the_motion_library(tmp_path):
    """handradar-synth source=motions (conf/source/motions.yaml: no folder read) with its classes replaced as
    docs/datasets.md#motions shows: per_class rows a class, each class's motions in turn."""
    out = tmp_path / "motions.h5"
    exe = Path(sys.executable).with_name("handradar-synth")
    res = subprocess.run([str(exe), "source=motions", "source.per_class=2", "~source.classes",
                          "+source.classes={push: [push], circle: [circle_cw, circle_ccw]}", f"out={out}",
                          f"paths.log_dir={tmp_path}/logs", f"synth.cache_dir={tmp_path}/cache", "chain.n_columns=8"],
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    assert res.stdout.strip().splitlines()[-1] == str(out)
    assert validate(out) == 4
    with h5py.File(out) as h5:
        assert json.loads(h5.attrs["classes"]) == ["push", "circle"]
        assert h5["labels"][()].tolist() == [0, 0, 1, 1]
        assert [m.decode() for m in h5["meta"]["motion"][()]] == ["push", "push", "circle_cw", "circle_ccw"]
        spec = h5["spectrograms"][()]
    assert spec.shape == (4, 64, 8) and spec.max() == 1.0
    assert not np.allclose(spec[0], spec[2], atol=0.05)  # a push is not a circle
    # modelling only: the slots are summed as simulated, no slot-profile cache (2.5 MB a row) is written
    assert not list((tmp_path / "cache").rglob("slot_profiles-*"))


def test_handradar_synth_on_sfinge3d_subset(sfinge3d_dir, tmp_path):
    """The console script on two SFINGE3D classes: a valid dataset with the source's labels."""
    root = tmp_path / "sf"
    for c in ("6", "10"):
        (root / "Dictionary" / c).mkdir(parents=True)
        for i in (1, 2):
            src = sfinge3d_dir / "Dictionary" / c / f"{i}.txt"
            (root / "Dictionary" / c / f"{i}.txt").write_text(src.read_text())
    out = tmp_path / "sf.h5"
    exe = Path(sys.executable).with_name("handradar-synth")
    res = subprocess.run([str(exe), f"source.root={root}", f"out={out}", f"paths.log_dir={tmp_path}/logs",
                          f"synth.cache_dir={tmp_path}/cache", "chain.n_columns=8"],
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    assert res.stdout.strip().splitlines()[-1] == str(out)
    assert validate(out) == 4
    with h5py.File(out) as h5:
        assert sorted(h5["labels"][()].tolist()) == [5, 5, 9, 9]  # pinch, swipe_left (folders 6, 10)
        assert json.loads(h5.attrs["classes"])[5] == "pinch"
        spec = h5["spectrograms"][()]
    assert spec.shape == (4, 64, 8) and spec.max() == 1.0
