"""LightningDataModule over a ``handradar.dataset/1`` file with a seeded stratified split.

The HDF5 file is never opened in ``__init__`` or ``setup`` for reading rows: each DataLoader
worker opens it on first access (see :class:`SpectrogramH5Dataset`), so h5py handles never cross
a fork.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader

from handradar.data.splits import stratified_partition
from handradar.data.torch_dataset import SpectrogramH5Dataset


class SpectrogramDataModule(L.LightningDataModule):
    """Train/val/test loaders over one dataset file.

    path: the HDF5 dataset. split: train/val/test fractions, stratified by label and fixed by
    ``seed``. with_skeleton: also return each row's skeleton window and hand mask.
    label_map: optional stored-label -> class remapping (rows whose label is not in it are dropped).
    """

    def __init__(self, path: str | Path, *, split: Sequence[float] = (0.7, 0.15, 0.15), seed: int = 0,
                 batch_size: int = 32, num_workers: int = 0, with_skeleton: bool = False,
                 label_map: dict[int, int] | None = None, pin_memory: bool = False) -> None:
        super().__init__()
        self.path = Path(path)
        self.split = tuple(float(x) for x in split)
        if len(self.split) != 3:
            raise ValueError(f"split must be three fractions (train, val, test), found {list(split)}")
        self.seed = int(seed)
        self.batch_size = int(batch_size)
        self.num_workers = int(num_workers)
        self.with_skeleton = with_skeleton
        self.label_map = None if label_map is None else {int(k): int(v) for k, v in label_map.items()}
        self.pin_memory = pin_memory
        self.indices: dict[str, np.ndarray] = {}
        self.datasets: dict[str, SpectrogramH5Dataset] = {}
        self.save_hyperparameters(ignore=["pin_memory"])

    def setup(self, stage: str | None = None) -> None:
        if self.datasets:
            return
        full = SpectrogramH5Dataset(self.path)  # validates the file; reads labels without keeping it open
        labels = full.labels()
        rows = np.arange(len(labels))
        if self.label_map is not None:
            keep = np.isin(labels, list(self.label_map))
            rows, labels = rows[keep], np.asarray([self.label_map[int(v)] for v in labels[keep]])
        self.classes = full.classes
        parts = stratified_partition(labels, self.split, self.seed)
        for name, part in zip(("train", "val", "test"), parts):
            self.indices[name] = rows[part]
            self.datasets[name] = SpectrogramH5Dataset(self.path, rows[part], with_skeleton=self.with_skeleton,
                                                       label_map=self.label_map)

    @property
    def num_classes(self) -> int:
        if self.label_map is not None:
            return len(set(self.label_map.values()))
        return len(self.classes)

    def _loader(self, name: str, shuffle: bool) -> DataLoader:
        if not self.datasets:
            self.setup()
        gen = torch.Generator().manual_seed(self.seed) if shuffle else None
        return DataLoader(self.datasets[name], batch_size=self.batch_size, shuffle=shuffle, generator=gen,
                          num_workers=self.num_workers, pin_memory=self.pin_memory,
                          persistent_workers=self.num_workers > 0)

    def train_dataloader(self) -> DataLoader:
        return self._loader("train", shuffle=True)

    def val_dataloader(self) -> DataLoader:
        return self._loader("val", shuffle=False)

    def test_dataloader(self) -> DataLoader:
        return self._loader("test", shuffle=False)
