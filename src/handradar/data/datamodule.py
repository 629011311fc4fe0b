"""LightningDataModules: the one way training jobs get their batches.

- :class:`TrainingRowsDataModule`: the classifiers' and the CGAN's training data, rows of one or
  more dataset files (the real few-shot rows, synthetic datasets) plus in-memory samples (CGAN),
  as ``(x (B, 1, 64, 32), y (B,))`` batches in the order of :class:`EpochSeededSampler` (or drawn
  with a fixed share per part, :class:`MixedSampler`).
- :class:`SpectrogramDataModule`: train / val / test loaders over one file with a seeded stratified
  split (``handradar.data.splits.stratified_partition``), optionally with skeleton windows.

:class:`EpochSeededSampler` makes an epoch's order a function of (seed, epoch) alone, so that a fit
resumed from a checkpoint sees the same batches as an uninterrupted one. HDF5 files are never
opened in ``__init__`` or ``setup`` for reading rows: each DataLoader worker opens them on first
access (see :class:`SpectrogramH5Dataset`), so h5py handles never cross a fork.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import lightning as L
import numpy as np
import torch
from torch.utils.data import ConcatDataset, DataLoader, Dataset, Sampler, TensorDataset

from handradar.data.splits import stratified_partition
from handradar.data.torch_dataset import SpectrogramH5Dataset


class EpochSeededSampler(Sampler[int]):
    """A permutation of ``range(n)`` that depends only on (seed, epoch); Lightning calls ``set_epoch``."""

    def __init__(self, n: int, seed: int) -> None:
        self.n, self.seed, self.epoch = n, int(seed), 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return self.n

    def generator(self) -> torch.Generator:
        """The random stream of the current (seed, epoch)."""
        return torch.Generator().manual_seed(self.seed * 1_000_003 + self.epoch)

    def __iter__(self) -> Iterator[int]:
        return iter(torch.randperm(self.n, generator=self.generator()).tolist())


class MixedSampler(EpochSeededSampler):
    """``n`` indices into concatenated parts of ``sizes`` rows per epoch: each from part p with probability
    ``shares[p]`` (normalised), a row of it uniformly, with replacement; a function of (seed, epoch) alone.

    It gives a small part (a few real rows) a fixed share of every batch beside a large one (synthetic rows)."""

    def __init__(self, sizes: Sequence[int], shares: Sequence[float], seed: int) -> None:
        if len(sizes) != len(shares) or any(s < 0 for s in shares) or sum(shares) <= 0:
            raise ValueError(f"shares {list(shares)} must be one non-negative number per part, not all 0")
        if any(n == 0 and p > 0 for n, p in zip(sizes, shares)):
            raise ValueError(f"a part without rows cannot have a share (sizes {list(sizes)}, shares {list(shares)})")
        self.sizes = [int(n) for n in sizes]
        super().__init__(sum(self.sizes), seed)
        self.p = torch.as_tensor([float(s) for s in shares], dtype=torch.float64) / float(sum(shares))
        self.offsets = torch.as_tensor(np.concatenate([[0], np.cumsum(self.sizes)[:-1]]), dtype=torch.long)

    def __iter__(self) -> Iterator[int]:
        g = self.generator()
        part = torch.multinomial(self.p, self.n, replacement=True, generator=g)
        within = (torch.rand(self.n, generator=g, dtype=torch.float64) *
                  torch.as_tensor(self.sizes, dtype=torch.float64)[part]).long()
        return iter((self.offsets[part] + within).tolist())


@dataclass(frozen=True)
class FileRows:
    """Rows of a dataset file; ``labels`` (one per row) replace the stored ones (e.g. a class subset)."""

    path: Path
    rows: np.ndarray | None = None  # None: every row
    labels: np.ndarray | None = None


@dataclass(frozen=True)
class ArrayRows:
    """Spectrograms (N, 64, 32) and labels (N,) held in memory (e.g. CGAN samples)."""

    x: np.ndarray
    y: np.ndarray


class _XY(Dataset):
    """``(spectrogram (1, 64, 32), label)`` pairs of file rows, read lazily in the worker."""

    def __init__(self, part: FileRows) -> None:
        self.rows = SpectrogramH5Dataset(part.path, part.rows)
        self.labels = None if part.labels is None else torch.as_tensor(np.asarray(part.labels, dtype=np.int64))
        if self.labels is not None and len(self.labels) != len(self.rows):
            raise ValueError(f"{part.path}: {len(self.labels)} labels for {len(self.rows)} rows")

    def __len__(self) -> int:
        return len(self.rows)

    def __getitem__(self, i: int) -> tuple[torch.Tensor, torch.Tensor]:
        item = self.rows[i]
        return item["spectrogram"], item["label"] if self.labels is None else self.labels[i]


class TrainingRowsDataModule(L.LightningDataModule):
    """Training batches of a classifier or the CGAN from ``parts`` (file rows and arrays), in order.

    Every epoch visits the concatenation of the parts in the order of :class:`EpochSeededSampler`
    (seed, epoch), or, with ``shares`` (one per part), as many rows drawn by :class:`MixedSampler`;
    ``batch_size`` is capped at the number of rows.
    """

    def __init__(self, parts: Sequence[FileRows | ArrayRows], *, batch_size: int, seed: int, num_workers: int = 0,
                 drop_last: bool = False, shares: Sequence[float] | None = None) -> None:
        super().__init__()
        if not parts:
            raise ValueError("a training datamodule needs at least one part")
        self.parts = list(parts)
        self.batch_size, self.seed = int(batch_size), int(seed)
        self.num_workers, self.drop_last = int(num_workers), bool(drop_last)
        self.dataset = ConcatDataset([_XY(p) if isinstance(p, FileRows) else
                                      TensorDataset(torch.as_tensor(np.asarray(p.x, np.float32))[:, None],
                                                    torch.as_tensor(np.asarray(p.y, np.int64))) for p in self.parts])
        self.shares = None if shares is None else [float(s) for s in shares]
        if self.shares is not None:  # checked here, not at the first batch
            MixedSampler([len(d) for d in self.dataset.datasets], self.shares, self.seed)

    def __len__(self) -> int:
        return len(self.dataset)

    def train_dataloader(self) -> DataLoader:
        n = len(self.dataset)
        sampler = (EpochSeededSampler(n, self.seed) if self.shares is None else
                   MixedSampler([len(d) for d in self.dataset.datasets], self.shares, self.seed))
        return DataLoader(self.dataset, batch_size=min(self.batch_size, n), sampler=sampler,
                          num_workers=self.num_workers, drop_last=self.drop_last,
                          persistent_workers=self.num_workers > 0)

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """Every training row in order: spectrograms (N, 64, 32) float32 and labels (N,)."""
        xs, ys = zip(*(self.dataset[i] for i in range(len(self.dataset))))
        return torch.stack(xs)[:, 0].numpy(), torch.stack(ys).numpy()


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
