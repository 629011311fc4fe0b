"""What the fast ingest path changed: block-buffered HDF5 rows, and the chain run on one torch thread."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
import torch

import handradar.data.ingest as ingest_mod
from handradar.data.hdf5 import DatasetWriter, open_writer, validate
from handradar.data.ingest import ingest
from handradar.errors import FormatError
from handradar.vocab import GESTURES
from tests.data.writer import Scene, write_recording


def test_buffered_rows_land_in_order_across_blocks(tmp_path, radar, chain, monkeypatch):
    monkeypatch.setattr(DatasetWriter, "BLOCK", 4)  # 11 rows: two full blocks and a partial one
    rng = np.random.default_rng(3)
    spec = rng.random((11, 64, 32), dtype=np.float32)
    skel = rng.normal(size=(11, 5, 2, 21, 3)).astype(np.float32)
    mask = rng.random((11, 5, 2)) > 0.5
    path = tmp_path / "d.h5"
    buf_spec, buf_skel = np.empty((64, 32), np.float32), np.empty((5, 2, 21, 3), np.float32)
    with open_writer(path, classes=GESTURES, radar=radar, chain=chain, skeleton_rate_hz=10.0, n_steps=5,
                     config_hash="h") as w:
        for i in range(11):
            buf_spec[...], buf_skel[...] = spec[i], skel[i]  # one buffer reused for every row, as callers may
            w.append(buf_spec, i % 10, buf_skel, mask[i], 0.5 * i, {"repetition": i, "subject": f"s{i % 3}"})
    assert validate(path) == 11
    with h5py.File(path, "r") as h5:
        np.testing.assert_array_equal(h5["spectrograms"][()], spec)
        np.testing.assert_array_equal(h5["skeletons"][()], skel)
        np.testing.assert_array_equal(h5["hand_mask"][()], mask)
        assert h5["labels"][()].tolist() == [i % 10 for i in range(11)]
        assert h5["window_start_s"][()].tolist() == [0.5 * i for i in range(11)]
        assert h5["meta/repetition"][()].tolist() == list(range(11))


def test_a_row_of_the_wrong_shape_fails_at_its_append(tmp_path, radar, chain):
    path = tmp_path / "d.h5"
    with pytest.raises(ValueError, match="broadcast"), open_writer(
            path, classes=GESTURES, radar=radar, chain=chain, skeleton_rate_hz=10.0, n_steps=5, config_hash="h") as w:
        w.append(np.zeros((64, 32), np.float32), 0, np.zeros((5, 2, 21, 3), np.float32), np.ones((5, 2), bool), 0.0, {})
        w.append(np.zeros((64, 31), np.float32), 0, np.zeros((5, 2, 21, 3), np.float32), np.ones((5, 2), bool), 0.0, {})
    assert list(tmp_path.iterdir()) == []  # nothing written


def test_chain_runs_on_one_torch_thread_and_the_count_is_restored(tmp_path, chain, monkeypatch):
    write_recording(tmp_path / "recs" / "a", Scene())
    write_recording(tmp_path / "recs" / "b", Scene(n_frames=10))  # shorter than one window: fails in the chain
    seen = []
    real = ingest_mod.recording_example

    def spy(*args, **kwargs):
        seen.append(torch.get_num_threads())
        return real(*args, **kwargs)

    monkeypatch.setattr(ingest_mod, "recording_example", spy)
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        summary = ingest(tmp_path / "recs", tmp_path / "d.h5", chain, progress=False)
        assert summary.written == 1 and seen == [1, 1] and torch.get_num_threads() == 2
        with pytest.raises(FormatError, match="fewer than"):
            ingest(tmp_path / "recs", tmp_path / "e.h5", chain, strict=True, progress=False)
        assert torch.get_num_threads() == 2  # restored after a failed run too
    finally:
        torch.set_num_threads(before)
