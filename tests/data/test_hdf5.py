"""The dataset file: atomic writer, validator, and ingest fuzzed with corrupted recordings."""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from handradar.data.hdf5 import open_writer, read_attrs, validate
from handradar.data.ingest import ingest
from handradar.errors import FormatError
from handradar.vocab import GESTURES
from tests.data.writer import Scene, write_recording


def _write(path, radar, chain, n=3, **overrides):
    with open_writer(path, classes=GESTURES, radar=radar, chain=chain, skeleton_rate_hz=10.0, n_steps=4,
                     config_hash="h") as w:
        for i in range(n):
            w.append(np.full((64, 32), 0.5, np.float32), i, np.zeros((4, 2, 21, 3), np.float32),
                     np.ones((4, 2), bool), 0.0, {"gesture": GESTURES[i], "angle_deg": 30.0 * i})
    with h5py.File(path, "a") as h5:
        for k, v in overrides.items():
            h5[k][...] = v


def test_writer_and_attrs(tmp_path, radar, chain):
    path = tmp_path / "d.h5"
    _write(path, radar, chain)
    assert validate(path) == 3
    attrs = read_attrs(path)
    assert attrs["radar"] == radar and attrs["chain"] == chain and attrs["classes"] == list(GESTURES)
    with h5py.File(path, "r") as h5:
        assert h5["meta/angle_deg"].dtype == np.float64 and h5["meta/gesture"][1].decode() == GESTURES[1]


def test_interrupted_writer_leaves_nothing(tmp_path, radar, chain):
    path = tmp_path / "d.h5"
    with pytest.raises(KeyboardInterrupt):
        with open_writer(path, classes=GESTURES, radar=radar, chain=chain, skeleton_rate_hz=10.0, n_steps=4,
                         config_hash="h") as w:
            w.append(np.zeros((64, 32), np.float32), 0, np.zeros((4, 2, 21, 3), np.float32), np.ones((4, 2), bool),
                     0.0, {})
            raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


def test_validate_finds_problems(tmp_path, radar, chain):
    path = tmp_path / "d.h5"
    _write(path, radar, chain, spectrograms=np.full((3, 64, 32), 1.5, np.float32))
    with pytest.raises(FormatError, match="values outside"):
        validate(path)
    _write(path, radar, chain, labels=np.array([0, 1, 10]))
    with pytest.raises(FormatError, match=r"labels must index the 10 classes, found values 0..10"):
        validate(path)
    path.write_bytes(b"not hdf5")
    with pytest.raises(FormatError, match="not a readable HDF5 file"):
        validate(path)


@pytest.fixture(scope="module")
def template(tmp_path_factory):
    return write_recording(tmp_path_factory.mktemp("tpl") / "rec", Scene())


@settings(max_examples=25, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(st.sampled_from(["radar.cfg", "leap.jsonl", "meta.json", "adc_data.bin"]), st.data())
def test_fuzz_ingest_strict_corrupt_file(tmp_path, radar, chain, template, name, data):
    """A recording with one corrupted file: strict ingest writes a valid dataset or raises
    FormatError, and never leaves a partial file."""
    work = Path(tempfile.mkdtemp(dir=tmp_path))
    shutil.copytree(template, work / "recs" / "rec")
    path = work / "recs" / "rec" / name
    raw = bytearray(path.read_bytes())
    kind = data.draw(st.sampled_from(["cut", "flip", "insert"]))
    pos = data.draw(st.integers(0, len(raw) - 1 if name != "adc_data.bin" else 4000))
    if kind == "cut":
        raw = raw[:pos]
    elif kind == "flip":
        raw[pos] = data.draw(st.integers(0, 255))
    else:
        raw[pos:pos] = data.draw(st.binary(min_size=1, max_size=8))
    path.write_bytes(bytes(raw))
    out = work / "out" / "d.h5"
    try:
        ingest(work / "recs", out, chain, strict=True, progress=False)
    except FormatError as exc:
        # the error names a file of this recording: the corrupted one, or another whose mismatch with
        # it the problem names (a changed .cfg makes adc_data.bin's size wrong "for the .cfg")
        assert exc.path is not None and exc.path.parent == path.parent, str(exc)
        assert exc.path.name in ("radar.cfg", "leap.jsonl", "meta.json", "adc_data.bin"), str(exc)
        assert exc.path.name == name or name.rsplit(".", 1)[1] in exc.problem, str(exc)
        assert str(exc).startswith(f"{exc.path}:") and exc.problem.strip()
        assert not out.parent.exists() or list(out.parent.iterdir()) == []
        return
    assert validate(out) == 1 and sorted(p.name for p in out.parent.iterdir()) == ["d.checks.json", "d.h5"]
