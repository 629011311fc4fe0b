"""Every error branch of the dataset validator (handradar.data.hdf5.read_attrs / validate), each on a
valid file corrupted for that branch alone: the FormatError names the file and the problem."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import h5py
import numpy as np
import pytest

from handradar.data.hdf5 import open_writer, validate
from handradar.errors import FormatError
from handradar.vocab import GESTURES

N, T = 3, 4


def _valid(path: Path, radar, chain) -> Path:
    """A valid 3-row file: spectrograms 0.5, labels 0..2, zero skeletons, both hands tracked."""
    with open_writer(path, classes=GESTURES, radar=radar, chain=chain, skeleton_rate_hz=10.0, n_steps=T,
                     config_hash="h") as w:
        for i in range(N):
            w.append(np.full((64, 32), 0.5, np.float32), i, np.zeros((T, 2, 21, 3), np.float32),
                     np.ones((T, 2), bool), 0.0, {"gesture": GESTURES[i], "angle_deg": 30.0 * i})
    return path


def _replace(name: str, data: np.ndarray) -> Callable[[h5py.File], None]:
    def edit(h5: h5py.File) -> None:
        del h5[name]
        h5.create_dataset(name, data=data)
    return edit


def _set_attr(name: str, value) -> Callable[[h5py.File], None]:
    def edit(h5: h5py.File) -> None:
        h5.attrs[name] = value
    return edit


def _del_attr(name: str) -> Callable[[h5py.File], None]:
    def edit(h5: h5py.File) -> None:
        del h5.attrs[name]
    return edit


def _delete(name: str) -> Callable[[h5py.File], None]:
    def edit(h5: h5py.File) -> None:
        del h5[name]
    return edit


def _meta_dataset(h5: h5py.File) -> None:  # 'meta' a dataset, not a group
    del h5["meta"]
    h5.create_dataset("meta", data=np.zeros(N))


def _meta_subgroup(h5: h5py.File) -> None:  # a group where a (N,) array belongs
    h5["meta"].create_group("nested")


def _add(name: str, data: np.ndarray) -> Callable[[h5py.File], None]:
    def edit(h5: h5py.File) -> None:
        h5.create_dataset(name, data=data)
    return edit


# (branch, corruption, the problem the message must state); one corruption per branch
BRANCHES = [
    ("format", _set_attr("format", "handradar.dataset/0"),
     r"attribute 'format' must be 'handradar.dataset/1', found 'handradar.dataset/0'"),
    ("missing dataset", _delete("skeletons"), r"missing dataset\(s\) \['skeletons'\]"),
    ("classes not JSON", _set_attr("classes", "grasp, circle"), r"attribute 'classes' or 'chain' is not valid"),
    ("chain incomplete", _set_attr("chain", json.dumps({"n_columns": 32})), r"attribute 'classes' or 'chain' is not valid"),
    ("classes not names", _set_attr("classes", json.dumps({"a": 1})), r"attribute 'classes' must be a JSON list of names"),
    ("radar_cfg", _set_attr("radar_cfg", "profileCfg 0 77 abc\n"), r"radar_cfg:1: profileCfg: expected 14 arguments, found 3"),
    ("spectrogram dtype", _replace("spectrograms", np.full((N, 64, 32), 0.5, np.float64)),
     r"spectrograms must be \(N, 64, 32\) float32, found \(3, 64, 32\) float64"),
    ("spectrogram rank", _replace("spectrograms", np.full((N, 64 * 32), 0.5, np.float32)),
     r"spectrograms must be .* found \(3, 2048\) float32"),
    ("spectrogram value", _replace("spectrograms", np.full((N, 64, 32), np.nan, np.float32)),
     r"spectrograms 0\.\.3 have values outside \[0, 1\]"),
    ("label dtype", _replace("labels", np.arange(N, dtype=np.int32)), r"labels must be \(3,\) int64, found \(3,\) int32"),
    ("label shape", _replace("labels", np.zeros((N, 1), np.int64)), r"labels must be \(3,\) int64, found \(3, 1\) int64"),
    ("label range", _replace("labels", np.array([0, -1, 2], np.int64)),
     r"labels must index the 10 classes, found values -1\.\.2"),
    ("skeleton shape", _replace("skeletons", np.zeros((N, T, 2, 20, 3), np.float32)),
     r"skeletons must be \(N, T, 2, 21, 3\) float32, found \(3, 4, 2, 20, 3\) float32"),
    ("skeleton dtype", _replace("skeletons", np.zeros((N, T, 2, 21, 3), np.float64)), r"skeletons must be .* float64"),
    ("hand_mask", _replace("hand_mask", np.ones((N, T + 1, 2), bool)), r"hand_mask must be \(3, 4, 2\), found \(3, 5, 2\)"),
    ("meta not a group", _meta_dataset, r"'meta' must be a group of \(N,\) arrays"),
    ("meta field length", _replace("meta/angle_deg", np.zeros(N - 1)), r"meta/angle_deg must have shape \(3,\), found \(2,\)"),
    ("meta field a group", _meta_subgroup, r"meta/nested must have shape \(3,\), found a group"),
    ("convention figure length", _add("convention/range_mirror_db", np.zeros(N - 1)),
     r"convention/range_mirror_db must be \(3,\) float \(dB; NaN where not measured\), found \(2,\) float64"),
    ("convention figure missing", _add("convention/other", np.zeros(N)),
     r"convention/range_mirror_db must be \(3,\) float .*, found None"),
    ("config_hash", _del_attr("config_hash"), r"missing attribute 'config_hash'"),
    ("code_version", _del_attr("code_version"), r"missing attribute 'code_version'"),
]


@pytest.fixture(scope="module")
def valid(tmp_path_factory, radar, chain) -> Path:
    return _valid(tmp_path_factory.mktemp("valid") / "d.h5", radar, chain)


def test_the_uncorrupted_file_is_valid(valid):
    assert validate(valid) == N


@pytest.mark.parametrize("branch, corrupt, problem", BRANCHES, ids=[b[0] for b in BRANCHES])
def test_each_validator_branch_names_the_file_and_the_problem(valid, tmp_path, branch, corrupt, problem):
    path = tmp_path / "corrupt.h5"
    path.write_bytes(valid.read_bytes())
    with h5py.File(path, "a") as h5:
        corrupt(h5)
    with pytest.raises(FormatError, match=problem) as info:
        validate(path)
    message = str(info.value)
    assert message.startswith(str(path)) and "\n" not in message  # one line, the file first


def test_not_an_hdf5_file_and_a_missing_file(tmp_path):
    bad = tmp_path / "d.h5"
    bad.write_bytes(b"not hdf5")
    with pytest.raises(FormatError, match=r"d\.h5: not a readable HDF5 file"):
        validate(bad)
    with pytest.raises(FormatError, match=r"missing\.h5: not a readable HDF5 file"):
        validate(tmp_path / "missing.h5")
