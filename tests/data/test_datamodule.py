"""SpectrogramDataModule: seeded stratified split, lazy HDF5 in DataLoader workers."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest
import torch

from handradar.data.datamodule import (
    ArrayRows,
    EpochSeededSampler,
    MixedSampler,
    FileRows,
    SpectrogramDataModule,
    TrainingRowsDataModule,
)
from handradar.data.datasets import load_arrays
from handradar.data.hdf5 import open_writer, validate
from handradar.data.splits import stratified_partition as stratified_split
from handradar.vocab import GESTURES

COUNTS = {0: 40, 3: 20, 7: 10}  # uneven classes


@pytest.fixture(scope="module")
def dataset(tmp_path_factory, radar, chain) -> Path:
    path = tmp_path_factory.mktemp("dm") / "d.h5"
    rng = np.random.default_rng(0)
    labels = np.concatenate([[c] * n for c, n in COUNTS.items()])
    rng.shuffle(labels)
    with open_writer(path, classes=GESTURES, radar=radar, chain=chain, skeleton_rate_hz=10.0, n_steps=16,
                     config_hash="test") as w:
        for i, c in enumerate(labels):
            spec = np.full((64, 32), i / len(labels), dtype=np.float32)  # row i is recognisable by its value
            skel = np.full((16, 2, 21, 3), i, dtype=np.float32)
            w.append(spec, int(c), skel, np.ones((16, 2), bool), 0.0,
                     {"gesture": GESTURES[c], "subject": f"s{i % 3}", "recording": f"r{i}"})
    assert validate(path) == len(labels)
    return path


def _labels(path: Path) -> np.ndarray:
    with h5py.File(path, "r") as h5:
        return h5["labels"][()]


def test_stratified_split_properties():
    labels = np.array([0] * 40 + [1] * 20 + [2] * 10 + [3] * 3)
    train, val, test = stratified_split(labels, (0.7, 0.15, 0.15), seed=1)
    assert len(np.intersect1d(train, val)) == len(np.intersect1d(train, test)) == len(np.intersect1d(val, test)) == 0
    assert np.array_equal(np.sort(np.concatenate([train, val, test])), np.arange(len(labels)))
    for c, n in ((0, 40), (1, 20), (2, 10)):
        assert (labels[train] == c).sum() == round(0.7 * n)
        assert (labels[val] == c).sum() == round(0.85 * n) - round(0.7 * n)
    again = stratified_split(labels, (0.7, 0.15, 0.15), seed=1)
    other = stratified_split(labels, (0.7, 0.15, 0.15), seed=2)
    assert all(np.array_equal(a, b) for a, b in zip((train, val, test), again))
    assert not np.array_equal(train, other[0])
    with pytest.raises(ValueError, match="sum to 1"):
        stratified_split(labels, (0.5, 0.2), seed=0)


def test_datamodule_split_is_seeded_and_stratified(dataset):
    dm = SpectrogramDataModule(dataset, seed=3, batch_size=8)
    dm.setup()
    labels = _labels(dataset)
    for c, n in COUNTS.items():
        assert (labels[dm.indices["train"]] == c).sum() == round(0.7 * n)
        assert (labels[dm.indices["test"]] == c).sum() == n - round(0.85 * n)
    assert dm.num_classes == 10 and dm.classes == list(GESTURES)
    same = SpectrogramDataModule(dataset, seed=3)
    same.setup()
    assert all(np.array_equal(dm.indices[k], same.indices[k]) for k in ("train", "val", "test"))


def test_loaders_with_two_workers(dataset):
    dm = SpectrogramDataModule(dataset, seed=0, batch_size=7, num_workers=2, with_skeleton=True)
    labels = _labels(dataset)
    for name, loader in (("train", dm.train_dataloader()), ("val", dm.val_dataloader()),
                         ("test", dm.test_dataloader())):
        seen = []
        for batch in loader:
            idx = batch["index"].numpy()
            seen.append(idx)
            assert batch["spectrogram"].shape[1:] == (1, 64, 32)
            # each row comes back from its own place in the file
            torch.testing.assert_close(batch["spectrogram"][:, 0, 0, 0], torch.as_tensor(idx / len(labels),
                                                                                       dtype=torch.float32))
            assert (batch["label"].numpy() == labels[idx]).all()
            assert (batch["skeleton"][:, 0, 0, 0, 0].numpy() == idx).all() and batch["hand_mask"].all()
        seen = np.concatenate(seen)
        assert np.array_equal(np.sort(seen), dm.indices[name])  # every row exactly once
        # the parent never holds an open handle that a fork could share
        assert dm.datasets[name]._h5 is None
    # the training order is shuffled, and the same for the same seed
    first = np.concatenate([b["index"].numpy() for b in dm.train_dataloader()])
    again = np.concatenate([b["index"].numpy() for b in SpectrogramDataModule(dataset, seed=0, batch_size=7)
                            .train_dataloader()])
    assert np.array_equal(first, again) and not np.array_equal(first, np.sort(first))


def test_label_map_keeps_a_subset(dataset):
    dm = SpectrogramDataModule(dataset, label_map={3: 0, 7: 1}, seed=0, batch_size=64)
    dm.setup()
    labels = _labels(dataset)
    all_rows = np.concatenate([dm.indices[k] for k in ("train", "val", "test")])
    assert sorted(all_rows.tolist()) == np.flatnonzero(np.isin(labels, [3, 7])).tolist()
    assert dm.num_classes == 2
    batch = next(iter(dm.train_dataloader()))
    assert set(batch["label"].tolist()) <= {0, 1}
    assert ((labels[batch["index"].numpy()] == 7) == (batch["label"].numpy() == 1)).all()


def test_training_rows_mix_files_and_arrays_in_a_seeded_resumable_order(fake_data):
    real = load_arrays(fake_data)
    rows = np.asarray([5, 1, 3])
    extra = ArrayRows(np.full((2, 64, 32), 0.5, np.float32), np.asarray([7, 8]))
    dm = TrainingRowsDataModule([FileRows(fake_data, rows), FileRows(fake_data, rows[:2], np.asarray([9, 9])), extra],
                                batch_size=4, seed=3)
    x, y = dm.arrays()
    assert np.array_equal(x[:3], real.x[rows]) and np.array_equal(y[:3], real.y[rows])  # file rows, in order
    assert np.array_equal(y[3:], [9, 9, 7, 8]) and np.array_equal(x[5:], extra.x)        # labels replaced; arrays
    batches = [b for b in dm.train_dataloader()]
    assert [len(b[1]) for b in batches] == [4, 3] and batches[0][0].shape == (4, 1, 64, 32)
    order = list(EpochSeededSampler(len(dm), 3))
    assert np.array_equal(torch.cat([b[1] for b in batches]).numpy(), y[order])  # the sampler's order
    again = [b for b in TrainingRowsDataModule([FileRows(fake_data, rows), FileRows(fake_data, rows[:2], np.asarray([9, 9])),
                                                extra], batch_size=4, seed=3).train_dataloader()]
    assert all(torch.equal(a[0], b[0]) for a, b in zip(batches, again))  # a function of the seed alone
    sampler = EpochSeededSampler(len(dm), 3)
    sampler.set_epoch(1)
    assert list(sampler) != order  # another epoch, another order
    with pytest.raises(ValueError, match="labels for"):
        TrainingRowsDataModule([FileRows(fake_data, rows, np.asarray([1]))], batch_size=2, seed=0)


def test_mixed_sampler_gives_each_part_its_share():
    """8 real rows beside 1600 synthetic with shares 0.5 / 0.5: about half of an epoch's 1608 draws are real
    (binomial: 3 standard deviations is 0.037), every real row drawn, all indices in range; (seed, epoch) fix it."""
    sampler = MixedSampler([8, 1600], [0.5, 0.5], seed=3)
    draws = np.array(list(sampler))
    assert len(draws) == 1608 and draws.min() >= 0 and draws.max() < 1608
    real = draws < 8
    assert abs(real.mean() - 0.5) < 3 * np.sqrt(0.25 / 1608)
    assert set(draws[real]) == set(range(8))
    assert list(sampler) == draws.tolist()
    sampler.set_epoch(1)
    assert list(sampler) != draws.tolist()
    assert (np.array(list(MixedSampler([8, 1600], [1.0, 0.0], seed=3))) < 8).all()
    for sizes, shares in (([8, 0], [0.5, 0.5]), ([8, 16], [0.5]), ([8, 16], [0.0, 0.0])):
        with pytest.raises(ValueError, match="share"):
            MixedSampler(sizes, shares, seed=3)
