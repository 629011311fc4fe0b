"""Measured spectrogram datasets through their manifest alone (handradar.data.measured), and the
measured job's split (handradar.data.splits.measured_split)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from handradar.data.datasets import load_arrays
from handradar.data.hdf5 import read_attrs, validate
from handradar.data.measured import MeasuredDataset, dataset_chain, read_manifest
from handradar.synthesis.measured import synthesis_radar
from handradar.data.splits import measured_split
from handradar.errors import FormatError, TooFewRows

SHARED_XIA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "xia2021"
CLASSES = {"wave": ["swipe_left", "swipe_right"], "poke": ["push"], "still": ["idle"]}


def stand_in(root: Path, *, n: int = 5, shape: tuple[int, int] = (32, 48), **manifest) -> Path:
    """Another layout than Xia et al.'s: NPY float rows (time x Doppler), class folders, no split folders.

    Row i of class c holds a blob at time 10 and Doppler bin 40 (the *low*-index end is approaching
    in this stand-in, zero Doppler at bin 20), on a floor of 1.0; values are not in [0, 1]."""
    for c, name in enumerate(CLASSES):
        (root / "rows" / name).mkdir(parents=True, exist_ok=True)
        for i in range(n):
            a = np.ones(shape, np.float32)
            a[10, 40] = 5.0 + c
            np.save(root / "rows" / name / f"r{i}.npy", a)
    m = {"format": "handradar.measured/1", "name": "standin", "root": "data",
         "rows": {"layout": "rows/{class}/*.npy", "test_fraction": 0.4, "seed": 3},
         "axes": {"doppler": "columns", "approaching": "low", "zero_doppler": 20},
         "radar": {"carrier_hz": 60.0e9}, "classes": CLASSES, **manifest}
    path = root / "manifest.yaml"
    (root / "data").symlink_to(root, target_is_directory=True)
    path.write_text(yaml.safe_dump(m, sort_keys=False))
    return path


def test_stand_in_through_its_manifest_alone(tmp_path):
    path = MeasuredDataset(stand_in(tmp_path), tmp_path / "cache").path()
    assert validate(path) == 15
    d = load_arrays(path)
    assert d.classes == list(CLASSES)
    assert d.x.shape == (15, 48, 32)  # (Doppler, time): the stand-in's own grid kept
    assert d.x.min() == 0.0 and d.x.max() == 1.0  # each image scaled on its own
    # low bins approach: bin 40 lies 20 bins on the receding side of zero (bin 20); in the project's orientation
    # (approaching high, zero at row 48 // 2 = 24) that is row 24 - 20 = 4, at time column 10
    assert np.unravel_index(np.argmax(d.x[0]), d.x[0].shape) == (4, 10)
    # the split rule: 40 % of each class's 5 rows (2) are test rows, the rest train; skeletons none
    for c in range(3):
        splits = d.meta["split"][d.y == c]
        assert sorted(splits) == ["test", "test", "train", "train", "train"]
    attrs = read_attrs(path)
    assert attrs["skeletons"] == "none" and "radar_cfg" not in attrs
    assert attrs["chain"].stft_len == 48 and attrs["chain"].n_columns == 32 and attrs["chain"].clutter_removal == "window"


def test_orientation_from_first_principles(tmp_path):
    """approaching high, zero at the centre: the image is kept as it is; low: mirrored about the zero row."""
    m_high = stand_in(tmp_path / "a", axes={"doppler": "columns", "approaching": "high", "zero_doppler": 24})
    d = load_arrays(MeasuredDataset(m_high, tmp_path / "c").path())
    assert np.unravel_index(np.argmax(d.x[0]), d.x[0].shape) == (40, 10)
    m_low = stand_in(tmp_path / "b", axes={"doppler": "columns", "approaching": "low", "zero_doppler": 24})
    d = load_arrays(MeasuredDataset(m_low, tmp_path / "c").path())
    # mirrored about row 24 (bin 23.5 of the flipped axis rolled back by one): 40 -> 24 - (40 - 24) = 8
    assert np.unravel_index(np.argmax(d.x[0]), d.x[0].shape) == (8, 10)


def test_frame_clutter_removal_reaches_the_chain(tmp_path):
    """processing.clutter_removal: frame (each frame's own mean, handradar.radar.chain) is the dataset chain's
    setting."""
    path = MeasuredDataset(stand_in(tmp_path, processing={"clutter_removal": "frame"}), tmp_path / "cache").path()
    assert read_attrs(path)["chain"].clutter_removal == "frame"


def test_grid_resampled(tmp_path):
    d = load_arrays(MeasuredDataset(stand_in(tmp_path, grid=[64, 16]), tmp_path / "c").path())
    assert d.x.shape == (15, 64, 16) and 0 <= d.x.min() and d.x.max() <= 1


def _edit(path: Path, **changes) -> Path:
    m = yaml.safe_load(path.read_text())
    for key, value in changes.items():
        node = m
        *parents, leaf = key.split("__")
        for p in parents:
            node = node[p]
        node[leaf] = value
    path.write_text(yaml.safe_dump(m, sort_keys=False))
    return path


@pytest.mark.parametrize("change, expected", [
    ({"classes__poke": ["jump"]}, "class 'poke': unknown motion 'jump'"),
    ({"classes__poke": []}, "class 'poke': no motion"),
    ({"rows__layout": "other/{class}/*.npy"}, "no such folder: class 'wave'"),
    ({"rows__test_fraction": 0.95}, "leaves no training row"),
    ({"axes__approaching": "up"}, "'axes.approaching' must be high, low or unknown"),
    ({"format": "x/1"}, "'format' must be 'handradar.measured/1'"),
    ({"radar__v_max_m_s": -1}, "'radar.v_max_m_s' must be a positive number or unknown"),
    ({"radar__clutter_removal": "frame"}, "'radar.clutter_removal' is now 'processing.clutter_removal'"),
    ({"radar__chirps_per_frame": 12.5}, "'radar.chirps_per_frame' must be a positive whole number or unknown"),
    ({"processing": {"clutter_removal": True}}, "'processing.clutter_removal' must be one of ['none', 'window'"),
    ({"processing": {"scale": "log"}}, "'processing.scale' must be one of ['db', 'linear'] or unknown"),
    ({"processing": {"normalise": "column"}}, "'processing.normalise' must be one of ['image', 'frame', 'none'] or unknown"),
    ({"processing": {"range": "max"}}, "'processing.range' must be one of ['sum', 'strongest']"),
    ({"processing": {"cfar": {"guard": 2}}}, "'processing.cfar' must be {guard: cells, training: cells, threshold_db"),
    ({"processing": {"threshold": 2}}, "'processing.threshold' must be a value in [0, 1) or null"),
    ({"processing": {"doppler_fft": 16}}, "'processing.doppler_fft' 16 is fewer than the images' 48 Doppler rows"),
    ({"processing": {"mti": True}}, "unknown processing step 'processing.mti'"),
    ({"processing": {"cfar": {"guard": 20, "training": 8, "threshold_db": 10}}}, "'processing': cfar (guard 20"),
])
def test_bad_manifest_is_one_line(tmp_path, change, expected):
    path = _edit(stand_in(tmp_path), **change)
    with pytest.raises(FormatError) as err:
        MeasuredDataset(path, tmp_path / "cache").path()
    assert expected in str(err.value) and "\n" not in str(err.value)
    assert not list((tmp_path / "cache").glob("*.h5"))  # nothing half-written


def test_bad_rows_are_one_line_naming_the_file(tmp_path):
    path = stand_in(tmp_path)
    for f in (tmp_path / "rows" / "still").glob("*.npy"):
        f.unlink()
    with pytest.raises(FormatError, match="class 'still' of split 'train' has no"):
        MeasuredDataset(path, tmp_path / "cache").path()
    np.save(tmp_path / "rows" / "still" / "a.npy", np.ones((32, 48)))
    np.save(tmp_path / "rows" / "still" / "b.npy", np.ones((30, 48)))
    with pytest.raises(FormatError, match=r"b.npy: image is 48 x 30 .*mixed sizes"):
        MeasuredDataset(path, tmp_path / "cache").path()
    (tmp_path / "rows" / "still" / "b.npy").write_bytes(b"not an array")
    with pytest.raises(FormatError, match=r"b.npy: unreadable image"):
        MeasuredDataset(path, tmp_path / "cache").path()
    assert not list((tmp_path / "cache").glob("*.h5"))


def test_missing_manifest_and_root(tmp_path):
    with pytest.raises(FormatError, match="manifest not found"):
        read_manifest(tmp_path / "none.yaml")
    path = stand_in(tmp_path)
    with pytest.raises(FormatError, match="no such folder.*data.root"):
        read_manifest(path, root=tmp_path / "elsewhere")


def test_measured_split_nested_and_validation_fixed():
    labels = np.concatenate([np.repeat(np.arange(3), 15), np.repeat(np.arange(3), 5)])
    splits = np.array(["train"] * 45 + ["A"] * 15)
    t4, v4 = measured_split(labels, splits, train="train", per_class=4, val_per_class=3, seed=1)
    t8, v8 = measured_split(labels, splits, train="train", per_class=8, val_per_class=3, seed=1)
    t_all, v_all = measured_split(labels, splits, train="train", per_class="all", val_per_class=3, seed=2)
    assert np.array_equal(v4, v8) and np.array_equal(v4, v_all)      # the same validation rows for every K and seed
    assert set(t4) < set(t8) and not set(t8) & set(v8)                # nested across K, disjoint from validation
    assert np.all(splits[t_all] == "train") and len(t_all) + len(v_all) == 45
    assert all(np.count_nonzero(labels[t4] == c) == 4 for c in range(3))


def test_measured_split_refuses_more_rows_than_a_class_has():
    """K beyond a class's training rows is an error naming the class (not K rows trained and labelled K), as is a
    class too small for its validation rows."""
    labels = np.repeat(np.arange(2), 10)
    splits = np.array(["train"] * 20)
    kw = dict(train="train", val_per_class=3, seed=1, classes=["wave", "poke"])
    with pytest.raises(TooFewRows, match=r"class 'wave' has 7 training rows besides its 3 validation rows: fewer than "
                                         r"split.per_class=500 \(split.per_class=all takes every one\)"):
        measured_split(labels, splits, per_class=500, **kw)
    assert len(measured_split(labels, splits, per_class=7, **kw)[0]) == 14
    with pytest.raises(TooFewRows, match="class 'wave' has 10 rows in split 'train': too few for 12 validation rows"):
        measured_split(labels, splits, per_class=1, **{**kw, "val_per_class": 12})


@pytest.mark.skipif(not (SHARED_XIA / "OpenSource").is_dir(), reason="Xia et al.'s DTI images are in ../shared only")
def test_xia2021_manifest(tmp_path):
    manifest = Path(__file__).resolve().parents[2] / "conf" / "manifests" / "xia2021.yaml"
    d = load_arrays(MeasuredDataset(manifest, tmp_path, root=SHARED_XIA).path())
    assert d.x.shape == (4000, 64, 64)
    assert [int(np.count_nonzero(d.meta["split"] == s)) for s in ("train", "A", "B")] == [3200, 400, 400]
    # the zero-Doppler band (row 31 of the images) lands on the centre row in every class mean
    means = np.stack([d.x[d.y == c].mean(axis=(0, 2)) for c in range(8)])
    assert np.all(np.abs(np.argmax(means, axis=1) - 32) <= 1)
    # clutter_removal: frame: zero Doppler itself is notched, the rows beside it kept, on the median training row of
    # every class but finger circle (whose motion crosses zero all along)
    train = d.meta["split"] == "train"
    band = np.stack([np.median(d.x[train & (d.y == c), 31:34].mean(axis=2), axis=0) for c in range(8)])
    notched = (band[:, 1] < band[:, 0]) & (band[:, 1] < band[:, 2])
    assert notched.tolist() == [c != d.classes.index("finger circle") for c in range(8)]


def test_synthesis_radar_and_chain_hold_the_dataset_grid(tmp_path):
    """v_max = lambda / (4 T_loop) (TI's velocity resolution note); chirps a frame zero-padded to the Doppler rows."""
    m = read_manifest(stand_in(tmp_path))  # 48 Doppler rows x 32 frames, doppler on the columns
    shape = (48, 32)
    radar = synthesis_radar(m, shape, {"v_max_m_s": 2.0, "frame_period_s": 0.05, "chirps_per_frame": 16})
    assert radar.n_loops == 16 and radar.frame_period_s == 0.05
    assert radar.wavelength_m / (4 * radar.loop_period_s) == pytest.approx(2.0)
    chain = dataset_chain(m, shape, radar.n_loops)
    assert (chain.stft_len, chain.stft_hop, chain.n_doppler, chain.n_columns) == (16, 16, 48, 32)
    assert synthesis_radar(m, shape, {"v_max_m_s": 2.0, "frame_period_s": 0.05, "chirps_per_frame": None}).n_loops == 48
    with pytest.raises(ValueError, match="expected 2 to the 48 bins of its Doppler FFT"):
        synthesis_radar(m, shape, {"v_max_m_s": 2.0, "frame_period_s": 0.05, "chirps_per_frame": 64})
    with pytest.raises(ValueError, match="do not fit"):
        synthesis_radar(m, shape, {"v_max_m_s": 0.5, "frame_period_s": 0.02, "chirps_per_frame": 48})


def test_zero_doppler_outside_the_axis_is_one_line(tmp_path):
    """A zero-Doppler index beyond the images' Doppler axis (99 of 48 bins) is refused, naming the manifest."""
    path = stand_in(tmp_path, axes={"doppler": "columns", "approaching": "low", "zero_doppler": 99})
    with pytest.raises(FormatError, match=r"manifest.yaml: 'axes.zero_doppler' 99 lies outside the Doppler axis "
                                          r"of r0.npy \(indices 0..47\)"):
        MeasuredDataset(path, tmp_path / "cache").path()
    assert not list((tmp_path / "cache").glob("*.h5"))
