"""The unpaired fit of a measured dataset's unknowns (handradar.synthesis.measured), checked on simulated rows
whose truth is known, and its two exact shortcuts (the dB floor, the Doppler mirror) against the chain itself."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import integrate, special, stats
import torch
import yaml

from handradar.data.datasets import load_arrays
from handradar.data.measured import Manifest, MeasuredDataset, dataset_chain, measured_manifest
from handradar.data.unknowns import MOTION, UNKNOWNS
from handradar.errors import FormatError
from handradar.gap.unpaired import unpaired_gap
from handradar.hand.motions import DEFAULT_RANGES
from handradar.radar.chain import ChainConfig, power_to_unit
from handradar.synthesis.measured import (
    DEEP_FLOOR_DB,
    PRIOR_KEPT_BELOW,
    finish_rows,
    fit_unknowns,
    mirror_doppler,
    motion_ranges,
    UnknownsFit,
    step_rows,
    synthesize_measured,
)

CLASSES = {"push": ["push"], "pull": ["pull"], "swipe": ["swipe_right"]}
TRUTH = {"v_max_m_s": 2.0, "frame_period_s": 0.04, "chirps_per_frame": 16, "dynamic_range_db": 20.0, "approaching": "low"}


@pytest.mark.parametrize("steps", [{}, {"scale": "linear"}, {"scale": "linear", "quantity": "magnitude"},
                                   {"normalise": "frame"}, {"normalise": "frame", "scale": "linear"}])
def test_finishing_deep_rows_is_the_chain_at_the_dataset_processing(steps):
    """Rows at the deep floor, finished at a floor D and a scaling, equal the chain run at D and that scaling on
    the power itself, where the power lies within the deep floor of each row's peak (three decades here)."""
    power = (1e-3 + torch.rand(4, 16, 8, dtype=torch.float64) ** 2) * 1e3
    deep = power_to_unit(power, ChainConfig(dynamic_range_db=DEEP_FLOOR_DB)).numpy()
    for floor in (10.0, 25.0, 60.0):
        direct = power_to_unit(power, ChainConfig(dynamic_range_db=floor, **steps)).numpy()
        finished = finish_rows(deep, {"dynamic_range_db": floor, **steps}, seed=0)
        np.testing.assert_allclose(finished, direct, atol=1e-6)
    if steps.get("scale") != "linear":
        with pytest.raises(ValueError, match="cannot show a 70 dB floor: the rows were simulated at 60 dB"):
            finish_rows(deep, {"dynamic_range_db": 70.0, **steps}, seed=0)


def measured_stand_in(root: Path, n: int = 8, truth: dict | None = None, processing: dict | None = None,
                      seed: int = 99, **manifest_fields) -> Path:
    """A measured dataset (NPY rows, 32 Doppler x 16 frames, approaching at the *low* rows) whose rows are the
    simulator's at ``truth`` (default TRUTH), another seed than the fit's: what the fit must recover. ``processing``:
    the manifest's processing section (the truth's own steps where it states them, unknown where the fit must)."""
    manifest = {"format": "handradar.measured/1", "name": "known", "root": ".",
                "rows": {"layout": "{split}/{class}/*.npy", "splits": {"train": "train", "test": "test"}},
                "axes": {"doppler": "rows", "approaching": "unknown"}, "values": [0, 1],
                "radar": {"carrier_hz": 77e9}, "classes": CLASSES, **({"processing": processing} if processing else {}),
                **manifest_fields}
    for split in ("train", "test"):
        for c in CLASSES:
            (root / split / c).mkdir(parents=True)
            np.save(root / split / c / "0.npy", np.zeros((32, 16), np.float32))
    (root / "m.yaml").write_text(yaml.safe_dump(manifest, sort_keys=False))
    template = MeasuredDataset(root / "m.yaml", root / "cache").path()  # the grid and classes the truth needs
    truth = load_arrays(synthesize_measured(template, truth or TRUTH, per_class=n, seed=seed, cache_dir=root / "synth"))
    for i, (x, y) in enumerate(zip(truth.x, truth.y)):
        np.save(root / "train" / list(CLASSES)[y] / f"{i + 1}.npy", x)
    return MeasuredDataset(root / "m.yaml", root / "cache").path()


def simulated_rows(real_path: Path, cache: Path, per_class: int = 8):
    """The fit's simulate callback on a stand-in: rows as simulated, None where the radar is no candidate."""
    def simulate(radar: dict):
        try:
            d = load_arrays(synthesize_measured(real_path, radar, per_class=per_class, seed=0, cache_dir=cache,
                                                finish=False))
        except ValueError:
            return None
        return d.x, d.y

    return simulate


def test_fit_recovers_known_unknowns(tmp_path):
    real_path = measured_stand_in(tmp_path)
    real = load_arrays(real_path)
    rows = np.flatnonzero((real.meta["split"] == "train") & (real.x.max(axis=(1, 2)) > 0))  # the simulated rows
    simulate = simulated_rows(real_path, tmp_path / "synth", per_class=16)
    grid = {"v_max_m_s": [0.5, 2.0, 4.0], "frame_period_s": [0.04, 0.08], "chirps_per_frame": [16, 32],
            "dynamic_range_db": [10.0, 20.0, 40.0], "approaching": ["high", "low"]}
    for objective in ("means", "moments"):
        fit = fit_unknowns(real.x[rows], real.y[rows], len(CLASSES), simulate, grid, n_boot=50, seed=0,
                           objective=objective)
        assert fit.values == {**TRUTH, "noise_db": None, "noise_looks": 1}, objective
    assert fit.shares["approaching"]["low"] > 0.9 and fit.n_rows == 24
    # label-free: one pooled class of the measured rows against one of the synthetic rows, no label on either side
    pooled = fit_unknowns(real.x[rows], np.zeros(len(rows), np.int64), 1, lambda r: (lambda m: m and (m[0], 0 * m[1]))(
        simulate(r)), grid, n_boot=50, seed=0)
    assert pooled.values == {**TRUTH, "noise_db": None, "noise_looks": 1} and pooled.shares["approaching"]["low"] > 0.9
    # v_max 0.5 m/s needs loops of 1.95 ms: 32 of them fit in no 40 ms frame, so that radar is no candidate (16 do)
    assert not any(c["v_max_m_s"] == 0.5 and c["frame_period_s"] == 0.04 and c["chirps_per_frame"] == 32
                   for c in fit.candidates)
    assert len(fit.candidates) == 11 * 3 * 2
    assert fit.ranges["dynamic_range_db"][0] <= 20.0 <= fit.ranges["dynamic_range_db"][1]


def test_noise_floor_closed_form():
    """Exponential noise power 30 dB below a row's peak: the background's mean dB is -30 + 10 log10(e) * (-0.5772)
    (E ln X = -Euler's gamma for X ~ Exp(1)), i.e. (60 - 32.51) / 60 on a 60 dB scale; the peak stays at 1."""
    x = np.zeros((4, 64, 64), np.float32)
    x[:, 10, 10] = 1.0
    y = finish_rows(x, {"noise_db": -30.0}, seed=0)
    background = np.delete(y.reshape(4, -1), 10 * 64 + 10, axis=1)
    assert background.mean() == pytest.approx((60 - 30 - 10 * np.log10(np.e) * 0.5772156649) / 60, abs=0.003)
    assert np.all(y[:, 10, 10] == 1.0)


@pytest.mark.parametrize("looks", [1, 8])
def test_noise_looks_closed_form(looks):
    """Noise power averaged over L cells is Gamma(L, 1/L) (scipy's law, not our code). On a pixel at the 60 dB floor
    (power 1e-6 of the peak) its dB is 10 log10(1e-6 + 10^(level / 10) G): moments integrated from that law; far
    above the floor they are the digamma / trigamma closed forms of 10 log10 G."""
    x = np.zeros((8, 64, 64), np.float32)
    x[:, 10, 10] = 1.0
    level = -30.0
    y = finish_rows(x, {"noise_db": level, "noise_looks": looks}, seed=1)
    db = np.delete(y.reshape(8, -1), 10 * 64 + 10, axis=1) * DEEP_FLOOR_DB - DEEP_FLOOR_DB
    law = stats.gamma(looks, scale=1.0 / looks)

    def moment(p: int) -> float:
        f = lambda g: (10 * np.log10(10 ** (-DEEP_FLOOR_DB / 10) + 10 ** (level / 10) * g)) ** p * law.pdf(g)  # noqa: E731
        return integrate.quad(f, 0, np.inf, limit=200)[0]

    mean, var = moment(1), moment(2) - moment(1) ** 2
    assert db.mean() == pytest.approx(mean, abs=4 * np.sqrt(var / db.size))  # 4 standard errors
    assert db.std() == pytest.approx(np.sqrt(var), rel=0.01)
    k = 10 * np.log10(np.e)  # the floor lifts little: the closed forms of 10 log10 G agree to 0.15 dB
    assert mean == pytest.approx(level + k * (special.digamma(looks) - np.log(looks)), abs=0.15)
    assert np.sqrt(var) == pytest.approx(k * np.sqrt(special.polygamma(1, looks)), abs=0.15)
    with pytest.raises(ValueError, match="positive count"):
        finish_rows(x, {"noise_db": level, "noise_looks": 0}, seed=1)


def test_fit_recovers_a_noise_floor(tmp_path):
    """Rows of the stand-in's truth with noise 25 dB below the peak, averaged over 8 cells: the fit names that level
    and those looks among others (the level alone is confounded with the looks in a class mean: the spread tells)."""
    real_path = measured_stand_in(tmp_path)
    truth = {**TRUTH, "noise_db": -25.0, "noise_looks": 8}
    sim = load_arrays(synthesize_measured(real_path, {**truth, "dynamic_range_db": DEEP_FLOOR_DB, "approaching": "high",
                                                      "noise_db": None}, per_class=8, seed=99,
                                          cache_dir=tmp_path / "synth"))
    measured_x = finish_rows(sim.x, truth, 5)  # the truth's rows with noise, another noise draw than the fit's
    simulate = simulated_rows(real_path, tmp_path / "synth")
    grid = {"v_max_m_s": [2.0], "frame_period_s": [0.04], "chirps_per_frame": [16], "dynamic_range_db": [20.0, 40.0],
            "approaching": ["low"], "noise_db": [None, -40.0, -25.0, -10.0], "noise_looks": [1, 8]}
    fit = fit_unknowns(measured_x, sim.y, len(CLASSES), simulate, grid, n_boot=20, seed=0, objective="moments")
    assert (fit.values["noise_db"], fit.values["noise_looks"]) == (-25.0, 8)
    assert fit.as_dict()["objective"].startswith("1 - SSIM of class-mean and class-spread")
    with pytest.raises(ValueError, match="unknown fit objective 'medians'"):
        fit_unknowns(measured_x, sim.y, len(CLASSES), simulate, grid, objective="medians")
    # without noise, its looks are no separate candidates: 2 floors x (1 noise-free + 3 levels x 2 looks)
    assert len(fit.candidates) == 2 * (1 + 3 * 2)


LAB = [{"scale": "linear", "quantity": "magnitude", "normalise": "frame"},
       {"scale": "db", "normalise": "frame"},
       {"scale": "linear", "quantity": "power", "normalise": "image"}]


@pytest.mark.parametrize("lab", LAB, ids=["linear magnitude per frame", "dB per frame", "linear power per image"])
def test_fit_recovers_a_labs_scaling(tmp_path, lab):
    """A stand-in made with a lab's scaling, which its manifest leaves unknown: the fit, label-free (one pooled class),
    names the scaling used among linear or dB, magnitude or power, per image or per frame."""
    unknown = {"scale": "unknown", "quantity": "unknown", "normalise": "unknown"}
    real_path = measured_stand_in(tmp_path, truth={**TRUTH, **lab}, processing=unknown)
    real = load_arrays(real_path)
    rows = np.flatnonzero((real.meta["split"] == "train") & (real.x.max(axis=(1, 2)) > 0))
    simulate = simulated_rows(real_path, tmp_path / "synth")
    grid = {"v_max_m_s": [2.0], "frame_period_s": [0.04], "chirps_per_frame": [16], "dynamic_range_db": [20.0, 40.0],
            "approaching": ["low"], "scale": ["db", "linear"], "quantity": ["power", "magnitude"],
            "normalise": ["image", "frame"]}
    fit = fit_unknowns(real.x[rows], np.zeros(len(rows), np.int64), 1, lambda r: (lambda m: m and (m[0], 0 * m[1]))(
        simulate(r)), grid, n_boot=0, seed=0)
    assert {k: fit.values[k] for k in lab} == lab
    if lab["scale"] == "db":
        assert fit.values["dynamic_range_db"] == TRUTH["dynamic_range_db"]
    # in dB the magnitude's image is the power's: one candidate for both; 2 floors x (1 + 2 linear) x 2 normalisations
    assert len(fit.candidates) == 2 * 3 * 2


@pytest.mark.parametrize("mode", ["sum", "strongest"])
def test_fit_recovers_a_labs_range_handling(tmp_path, mode):
    """A stand-in made by summing the gated range bins, or by each frame's strongest bin, which its manifest leaves
    unknown: the label-free fit, one simulation per candidate, names the one used. The stand-in shares the fit's
    motion draws (seed 0), so this checks that each candidate's range handling reaches its rows. With independent
    draws the trace lies below the class means' sampling spread: at 24 rows a class, stand-ins made with the strongest
    bin gave pooled gaps of 0.059 (strongest) against 0.054 (sum), the wrong way (docs/datasets.md#processing)."""
    real_path = measured_stand_in(tmp_path, truth={**TRUTH, "range": mode}, processing={"range": "unknown"}, seed=0)
    real = load_arrays(real_path)
    rows = np.flatnonzero((real.meta["split"] == "train") & (real.x.max(axis=(1, 2)) > 0))
    simulate = simulated_rows(real_path, tmp_path / "synth")
    grid = {"v_max_m_s": [2.0], "frame_period_s": [0.04], "chirps_per_frame": [16], "dynamic_range_db": [20.0],
            "approaching": ["low"], "range": ["sum", "strongest"]}
    fit = fit_unknowns(real.x[rows], np.zeros(len(rows), np.int64), 1, lambda r: (lambda m: m and (m[0], 0 * m[1]))(
        simulate(r)), grid, n_boot=0, seed=0)
    assert fit.values["range"] == mode and len(fit.candidates) == 2
    gaps = {c["range"]: c["gap"] for c in fit.candidates}
    assert gaps[mode] < gaps[{"sum": "strongest", "strongest": "sum"}[mode]]


def test_a_value_at_the_edge_of_its_grid_is_reported(tmp_path):
    """The truth's 2 m/s beyond a grid of 0.7-1.5 m/s: the fit chooses the grid's edge and says so, with how to widen
    it; inside a grid that holds the truth, nothing is reported."""
    real_path = measured_stand_in(tmp_path)
    real = load_arrays(real_path)
    rows = np.flatnonzero((real.meta["split"] == "train") & (real.x.max(axis=(1, 2)) > 0))
    simulate = simulated_rows(real_path, tmp_path / "synth")
    base = {"frame_period_s": [0.04], "chirps_per_frame": [16], "dynamic_range_db": [20.0], "approaching": ["low"]}
    edge = fit_unknowns(real.x[rows], real.y[rows], len(CLASSES), simulate, {**base, "v_max_m_s": [0.7, 1.0, 1.5]},
                        n_boot=10, seed=0)
    assert edge.values["v_max_m_s"] == 1.5 and edge.edges == ["v_max_m_s"]
    assert "v_max_m_s 1.5" in edge.summary() and "AT THE EDGE of its grid" in edge.summary()
    assert "synth.measured.fit.grid.v_max_m_s=[...]" in edge.summary() and "deepest" not in edge.summary()
    assert UnknownsFit.from_dict(edge.as_dict()).edges == ["v_max_m_s"]
    inside = fit_unknowns(real.x[rows], real.y[rows], len(CLASSES), simulate, {**base, "v_max_m_s": [1.0, 2.0, 4.0]},
                          n_boot=10, seed=0)
    assert inside.values["v_max_m_s"] == 2.0 and inside.edges == [] and "EDGE" not in inside.summary()
    deepest = UnknownsFit(values={"dynamic_range_db": DEEP_FLOOR_DB}, candidates=[], shares={}, ranges={}, n_rows=3,
                          edges=["dynamic_range_db"])
    assert "at the deepest the simulated rows keep (60 dB)" in deepest.summary()


def test_stated_steps_reach_the_synthetic_rows(tmp_path):
    """A manifest stating an MTI canceller, the central 32 of a 64-bin Doppler FFT, the strongest range bin, a
    CA-CFAR and a threshold: the synthetic rows keep 32 rows, hold only cells the CFAR passed (many exact zeros)
    and no value between 0 and the threshold; the dataset's chain says each step."""
    processing = {"clutter_removal": "mti", "mti_lag": 2, "doppler_fft": 64, "range": "strongest",
                  "cfar": {"guard": 4, "training": 4, "threshold_db": 3.0}, "threshold": 0.2}
    real_path = measured_stand_in(tmp_path, processing=processing)
    chain = dataset_chain(*measured_manifest(real_path))
    assert (chain.clutter_removal, chain.mti_lag, chain.n_fft, chain.n_doppler, chain.range_mode, chain.cfar,
            chain.threshold) == ("mti", 2, 64, 32, "strongest", (4, 4, 3.0), 0.2)
    x = load_arrays(synthesize_measured(real_path, TRUTH, per_class=4, seed=0, cache_dir=tmp_path / "synth")).x
    assert x.shape[1:] == (32, 16)
    assert (x == 0).mean() > 0.5 and not ((x > 0) & (x < 0.2)).any() and x.max() == 1.0


def test_the_report_names_a_misstated_clutter_filter(tmp_path):
    """Stand-in rows made without clutter removal (the hand's zero-Doppler line in every column) under a manifest that
    states each frame's removal: of every step switched on alone, the one simulated anew without it brings each
    class's synthetic mean closest to the measured one; a step the chain already takes is not offered."""
    measured_stand_in(tmp_path, n=16, processing={"clutter_removal": "none"})
    manifest = yaml.safe_load((tmp_path / "m.yaml").read_text())
    (tmp_path / "stated.yaml").write_text(yaml.safe_dump({**manifest, "processing": {"clutter_removal": "frame"}}))
    real_path = MeasuredDataset(tmp_path / "stated.yaml", tmp_path / "cache").path()
    real = load_arrays(real_path)
    rows = (real.meta["split"] == "train") & (real.x.max(axis=(1, 2)) > 0)
    made = dict(per_class=16, seed=0, cache_dir=tmp_path / "synth")
    synth = load_arrays(synthesize_measured(real_path, TRUTH, **made))
    steps = step_rows(real_path, TRUTH, **made)
    assert {"no clutter removal", "MTI canceller (lag 1)", "strongest range bin", "linear power"} <= set(steps)
    assert "clutter removal per frame" not in steps and "sum over the range gate" not in steps
    assert all(x.shape == synth.x.shape for x in steps.values())
    report = unpaired_gap(real.x[rows], real.y[rows], synth.x, synth.y, list(CLASSES), steps)
    assert {c: e["explained_by"] for c, e in report["classes"].items()} == dict.fromkeys(CLASSES, "no clutter removal")


def test_hands_drawn_beyond_the_range_gate_are_an_error(tmp_path):
    """A manifest drawing one class's hands 0.5-0.9 m away under the default 0.08-0.70 m range gate: synthesis names
    the manifest, the range and the gate instead of simulating hands the chain cuts; a wider gate takes them."""
    measured_stand_in(tmp_path)
    manifest = yaml.safe_load((tmp_path / "m.yaml").read_text())
    far = {**manifest, "classes": {**CLASSES, "pull": {"motions": ["pull"], "ranges": {"distance_m": [0.5, 0.9]}}}}

    def synthesize(name: str, **fields) -> Path:
        (tmp_path / f"{name}.yaml").write_text(yaml.safe_dump({**far, **fields}))
        real_path = MeasuredDataset(tmp_path / f"{name}.yaml", tmp_path / "cache").path()
        return synthesize_measured(real_path, TRUTH, per_class=2, seed=0, cache_dir=tmp_path / "synth")

    message = r"manifest 'known' draws the hands 0.2-0.9 m from the radar.*range_gate_m \[0.08, 0.7\]"
    with pytest.raises(FormatError, match=message):
        synthesize("far")
    assert load_arrays(synthesize("wide", processing={"range_gate_m": [0.08, 1.0]})).x.shape[0] == 6


def test_a_hand_held_in_view_returns_in_nearly_every_column(tmp_path):
    """The motions hold the hand in the beam before and after the gesture; with the physiological tremor a dataset's
    hands have (motion_ranges.tremor_mm 0.5), each frame's clutter removal leaves it a return above a 60 dB floor in
    99 % of the columns or more, where a perfectly still hand leaves the columns outside the gesture at the floor
    (about 70 % with a return). Scaled per frame, every column shows its own peak whatever the hand does."""
    def columns_with_a_return(tremor_mm: float) -> float:
        root = tmp_path / f"t{tremor_mm}"
        path = measured_stand_in(root, processing={"clutter_removal": "frame"},
                                 motion_ranges={"tremor_mm": [tremor_mm, tremor_mm]})
        values = {**TRUTH, "approaching": "high", "dynamic_range_db": DEEP_FLOOR_DB}
        x = load_arrays(synthesize_measured(path, values, per_class=4, seed=1, cache_dir=root / "synth")).x
        return float((x.max(axis=1) > 0).mean())

    assert columns_with_a_return(0.5) >= 0.99 and columns_with_a_return(0.0) < 0.8


def test_mirror_doppler_about_the_zero_row():
    x = np.zeros((2, 64, 5))
    x[:, 32 + 7, 1] = 1.0          # 7 rows above zero (row 32)
    x[:, 32, 2] = 2.0              # zero Doppler stays
    y = mirror_doppler(x)
    assert y[0, 32 - 7, 1] == 1.0 and y[0, 32, 2] == 2.0
    assert np.array_equal(mirror_doppler(y), x)


def test_one_row_per_class_has_no_bootstrap_uncertainty():
    """With one row in a class every resample is the same rows: the fit says it cannot estimate its uncertainty
    rather than report each value "chosen by 100 % of resamples"."""
    rng = np.random.default_rng(0)
    real_x, real_y = rng.random((2, 8, 6)).astype(np.float32), np.array([0, 1])

    def simulate(radar: dict):
        return np.clip(real_x + 0.01 * radar["v_max_m_s"], 0, 1), real_y

    grid = {"v_max_m_s": [0.0, 5.0], "frame_period_s": [0.04], "dynamic_range_db": [60.0], "approaching": ["high"]}
    fit = fit_unknowns(real_x, real_y, 2, simulate, grid, n_boot=30, seed=0)
    assert fit.values["v_max_m_s"] == 0.0 and fit.n_boot == 0 and fit.shares == {} and fit.ranges == {}
    assert "uncertainty not estimated: a class has fewer than 2 rows" in fit.summary()
    assert UnknownsFit.from_dict(fit.as_dict()) == fit
    two = fit_unknowns(np.concatenate([real_x, real_x]), np.array([0, 1, 0, 1]), 2, simulate, grid, n_boot=30, seed=0)
    assert two.n_boot == 30 and "chosen by 100% of resamples" in two.summary()


def test_the_radars_resamples_redraw_the_synthetic_rows():
    """Measured rows that agree closely (a lobe at Doppler row 16, jittered by a tenth of a row) against 4 synthetic
    rows a candidate whose lobes scatter by 3 rows, the candidates half a row apart: resamples of the measured
    rows alone would agree on one candidate every time; redrawing the synthetic rows as well, the ranking moves, and
    the fit says so."""
    d = np.arange(32.0)[:, None] + np.zeros((1, 16))

    def lobes(centres: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.exp(-0.5 * ((d - centres[:, None, None]) / 2.0) ** 2).astype(np.float32), np.zeros(len(centres), int)

    real_x, real_y = lobes(16 + np.random.default_rng(1).uniform(-0.1, 0.1, 200))
    jitter = np.array([-3.0, -1.0, 1.0, 3.0])  # the same draws for every candidate, symmetric about row 16

    def simulate(radar: dict):
        return lobes(16 + jitter + (radar["v_max_m_s"] - 2.0))

    fit = fit_unknowns(real_x, real_y, 1, simulate, {"v_max_m_s": [1.0, 1.5, 2.0, 2.5, 3.0]}, n_boot=100, seed=0)
    shares = fit.shares["v_max_m_s"]
    assert max(shares.values()) < 0.5 and len(shares) >= 3, shares  # the measured rows alone: 2.0 in 100 %
    assert fit.values["v_max_m_s"] == 2.0  # on all rows: the candidate whose lobes centre on row 16


def test_motion_unknowns_move_the_prior_ranges():
    """A motion unknown multiplies (factor) or shifts (shift) the manifest's range, else the library's default; the
    class's own range of that field moves with it; a shift keeps tremor at or above 0; a value that keeps the prior
    leaves the ranges (and so every cache key) as they were."""
    m = Manifest(path=Path("m.yaml"), name="m", root=Path("."), layout="", splits={}, train="train", test=[],
                 classes={"swipe": ["swipe_right"]}, folders={}, doppler_axis=0, approaching="unknown",
                 zero_doppler=None, grid=None, values=None, radar={}, processing={},
                 motion_ranges={"speed": (0.5, 1.0), "tremor_mm": (0.2, 1.0)},
                 class_ranges={"swipe": {"speed": (0.8, 0.8), "turns": (2.0, 3.0)}})
    assert motion_ranges(m, {k: UNKNOWNS[k].identity for k in MOTION}) == motion_ranges(m) == (
        m.motion_ranges, m.class_ranges)
    shared, by_class = motion_ranges(m, {"speed_factor": 1.5, "tremor_shift_mm": -0.5, "azimuth_shift_deg": 10.0,
                                         "distance_factor": 0.5})
    lo, hi = DEFAULT_RANGES["distance_m"]
    assert shared == {"speed": (0.75, 1.5), "tremor_mm": (0.0, 0.5), "azimuth_deg": (-10.0, 30.0),
                      "distance_m": (0.5 * lo, 0.5 * hi)}
    assert by_class == {"swipe": {"speed": pytest.approx((1.2, 1.2)), "turns": (2.0, 3.0)}}


@pytest.mark.parametrize("truth", [0.67, 1.5])
def test_fit_recovers_the_motions_speed(tmp_path, truth):
    """A stand-in whose hands move 1.5 times (or 0.67 times) as fast as the prior's, other draws than the fit's: the
    label-free fit, radar known, moves the speed from its prior to the truth, every resample agreeing."""
    real_path = measured_stand_in(tmp_path, n=16, truth={**TRUTH, "speed_factor": truth})
    real = load_arrays(real_path)
    rows = np.flatnonzero((real.meta["split"] == "train") & (real.x.max(axis=(1, 2)) > 0))
    simulate = simulated_rows(real_path, tmp_path / "synth", per_class=16)
    grid = {**{k: [v] for k, v in TRUTH.items()}, "speed_factor": list(UNKNOWNS["speed_factor"].grid)}
    fit = fit_unknowns(real.x[rows], np.zeros(len(rows), np.int64), 1, lambda r: (lambda m: m and (m[0], 0 * m[1]))(
        simulate(r)), grid, n_boot=50, seed=0)
    assert fit.values["speed_factor"] == truth and fit.shares["speed_factor"][str(truth)] == 1.0 and not fit.kept
    assert fit.edges == ["speed_factor"]  # 0.67 and 1.5 are the grid's edges: said so
    # the radar (fixed) at the prior, the speed's three candidates, the radar again at the fitted speed: one pass
    assert len(fit.candidates) == 1 + 3 + 1 and fit.passes == 1


def _blobs(speed: float, v_max: float, seed: int, n: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """n rows of one class (32 x 32): a Gaussian blob whose Doppler width is 4 speed / v_max rows and whose duration
    is 6 / speed columns, its centre jittered by up to a pixel: a faster hand and a lower v_max widen it alike."""
    rng = np.random.default_rng(seed)
    d, t = np.arange(32.0)[:, None], np.arange(32.0)[None, :]
    rows = [np.exp(-0.5 * (((d - 16 - rng.uniform(-1, 1)) / (4 * speed / v_max)) ** 2
                           + ((t - 16 - rng.uniform(-1, 1)) / (6 / speed)) ** 2)) for _ in range(n)]
    return np.stack(rows).astype(np.float32), np.zeros(n, np.int64)


def test_a_second_pass_refits_the_radar_at_the_fitted_motions():
    """Speed and v_max trade in a row's Doppler width; only the speed sets its duration. Rows of speed x 1.5 at
    v_max 2: the radar fitted at the prior's speed chooses v_max 1.5 (the width alone), the motions then move the
    speed to 1.5 (the duration), and only a second pass at that speed finds v_max 2 again."""
    real_x, real_y = _blobs(1.5, 2.0, seed=1)
    grid = {"v_max_m_s": [1.0, 1.5, 2.0, 3.0], "speed_factor": [0.67, 1.0, 1.5]}
    simulate = lambda v: _blobs(v["speed_factor"], v["v_max_m_s"], seed=2)  # noqa: E731
    one = fit_unknowns(real_x, real_y, 1, simulate, grid, n_boot=20, seed=0, passes=1)
    assert (one.values["v_max_m_s"], one.values["speed_factor"], one.passes) == (1.5, 1.5, 1)
    two = fit_unknowns(real_x, real_y, 1, simulate, grid, n_boot=20, seed=0)
    assert (two.values["v_max_m_s"], two.values["speed_factor"], two.passes) == (2.0, 1.5, 2)
    assert two.shares["v_max_m_s"]["2.0"] == 1.0 and "2 passes" in two.summary()
    # the candidates of both passes: 4 radars at the prior's speed, 3 speeds, 4 radars again, 3 speeds again
    assert len(two.candidates) == 4 + 3 + 4 + 3 and UnknownsFit.from_dict(two.as_dict()).passes == 2


def test_a_motion_the_rows_cannot_tell_keeps_its_prior(tmp_path):
    """A stand-in drawn at the prior of every motion (other draws than the fit's): with all five motion unknowns
    searched, class by class, none leaves its prior; where a candidate beat the prior on all rows but not in 97.5 %
    of resamples the fit says so (``kept``: the synthetic rows' own sampling, not the truth)."""
    real_path = measured_stand_in(tmp_path, n=16)
    real = load_arrays(real_path)
    rows = np.flatnonzero((real.meta["split"] == "train") & (real.x.max(axis=(1, 2)) > 0))
    grid = {**{k: [v] for k, v in TRUTH.items()}, **{k: list(UNKNOWNS[k].grid) for k in MOTION}}
    fit = fit_unknowns(real.x[rows], real.y[rows], len(CLASSES), simulated_rows(real_path, tmp_path / "synth", 16),
                       grid, n_boot=50, seed=0)
    assert {k: fit.values[k] for k in MOTION} == {k: UNKNOWNS[k].identity for k in MOTION}
    # the radar at the prior, then 3 candidates each, but tremor's -0.5 mm clips to the prior's 0 mm: one candidate
    assert len(fit.candidates) == 1 + 3 + 2 + 3 + 3 + 3
    for k, held in fit.kept.items():
        assert held["wins"] < PRIOR_KEPT_BELOW and f"{k} {UNKNOWNS[k].identity}" in fit.summary()
        assert "the prior kept" in fit.summary()
    assert UnknownsFit.from_dict(fit.as_dict()).kept == fit.kept
