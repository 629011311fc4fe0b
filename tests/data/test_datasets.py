"""Real-data sources (HDF5 file, ingested recordings, reference world) and provider output checks."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from handradar.data import datasets
from handradar.data.datasets import (
    DatasetFile,
    RecordingsFolder,
    ReferenceWorld,
    file_hash,
    load_arrays,
)
from handradar.errors import FormatError, HandradarError
from handradar.radar.chain import ChainConfig
from handradar.synthesis.providers import load_synthetic
from tests.tasks.fakes import default_radar, write_fake_dataset


def test_hdf5_source(fake_data: Path, tmp_path: Path):
    assert DatasetFile(fake_data).path() == fake_data.resolve()
    with pytest.raises(FormatError, match="nope.h5: dataset file not found"):
        DatasetFile(tmp_path / "nope.h5").path()
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"not hdf5")
    with pytest.raises(FormatError, match="bad.h5: not a readable HDF5 file"):
        DatasetFile(bad).path()


def test_load_arrays(fake_data: Path):
    data = load_arrays(fake_data)
    assert data.x.shape == (80, 64, 32) and data.x.dtype == np.float32
    assert np.bincount(data.y).tolist() == [8] * 10
    assert data.classes[0] == "grasp" and set(data.meta) >= {"gesture", "subject", "angle_deg", "hands", "occlusion"}
    sub = load_arrays(fake_data, np.array([3, 13]))
    assert sub.y.tolist() == [3, 3] and sub.meta["gesture"].tolist() == ["circle", "circle"]
    assert file_hash(fake_data) == file_hash(fake_data) and len(file_hash(fake_data)) == 16


def test_load_arrays_rejects_labels_outside_the_classes(tmp_path: Path):
    f = write_fake_dataset(tmp_path / "d.h5", per_class=1, n_classes=3)
    with h5py.File(f, "a") as h5:
        h5["labels"][0] = 7
    with pytest.raises(FormatError, match=r"d.h5: labels must lie in \[0, 3\)"):
        load_arrays(f)


def test_recordings_source_ingests_once_per_content(tmp_path: Path, monkeypatch):
    root = tmp_path / "recs"
    for name in ("r1", "r2"):
        (root / name).mkdir(parents=True)
        for f in ("radar.cfg", "adc_data.bin", "leap.jsonl", "meta.json"):
            (root / name / f).write_text(f"{name}/{f}")
    calls = []

    def fake_ingest(rec_root, out, chain, **kw):
        calls.append(Path(out))
        write_fake_dataset(Path(out), per_class=1, n_classes=2)
        from handradar.data.ingest import IngestSummary

        return IngestSummary(found=2, written=2)

    monkeypatch.setattr("handradar.data.datasets.ingest", fake_ingest)
    src = RecordingsFolder(root, ChainConfig(), tmp_path / "cache")
    first = src.path()
    assert first.parent == (tmp_path / "cache").resolve() and first.name.startswith("recordings-")
    assert src.path() == first and len(calls) == 1  # cached
    assert RecordingsFolder(root, ChainConfig(dynamic_range_db=25.0), tmp_path / "cache").path() != first
    (root / "r2" / "meta.json").write_text("changed content")
    os.utime(root / "r2" / "meta.json", ns=(1, 1))
    assert src.path() != first and len(calls) == 3  # a changed recording is ingested again
    # two jobs of a sweep asking at once: one ingests, the other waits and reads the same file
    import threading
    import time

    (root / "r1" / "meta.json").write_text("changed again")
    os.utime(root / "r1" / "meta.json", ns=(2, 2))
    slow = fake_ingest

    def fake_ingest_slowly(*a, **kw):
        time.sleep(0.3)
        return slow(*a, **kw)

    monkeypatch.setattr("handradar.data.datasets.ingest", fake_ingest_slowly)
    got: list[Path] = []
    jobs = [threading.Thread(target=lambda: got.append(RecordingsFolder(root, ChainConfig(), tmp_path / "cache").path()))
            for _ in range(2)]
    for j in jobs:
        j.start()
    for j in jobs:
        j.join()
    assert len(calls) == 4 and got[0] == got[1]
    shutil.rmtree(root)
    with pytest.raises(FormatError, match="recordings folder not found"):
        src.path()


def test_world_source_calls_the_builder(fake_data: Path, tmp_path: Path, monkeypatch):
    seen = {}

    def build(world_cfg, radar, chain, cache_dir):
        seen.update(world=world_cfg, cache=cache_dir)
        return fake_data

    monkeypatch.setattr(datasets, "_test_builder", build, raising=False)
    src = ReferenceWorld("handradar.data.datasets._test_builder", default_radar(), ChainConfig(), tmp_path, world={"n": 3})
    assert src.path() == fake_data.resolve() and seen == {"world": {"n": 3}, "cache": tmp_path}
    with pytest.raises(HandradarError, match="'no.such.builder' is not available"):
        ReferenceWorld("no.such.builder", default_radar(), ChainConfig(), tmp_path).path()


def test_load_synthetic_checks_the_contract(fake_data: Path, tmp_path: Path):
    labels = load_arrays(fake_data).y
    assert len(load_synthetic(fake_data, labels)) == 80
    with pytest.raises(FormatError, match="has 80 rows, the provider was asked for 79"):
        load_synthetic(fake_data, labels[:79])
    with pytest.raises(FormatError, match="synthetic row 0 has label 0, the requested row's label is 9"):
        load_synthetic(fake_data, np.roll(labels, 1))
    with pytest.raises(FormatError, match=r"must be \(N, 64, 16\)"):
        load_synthetic(fake_data, labels, shape=(64, 16))
