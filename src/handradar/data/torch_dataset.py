"""torch Dataset over a ``handradar.dataset/1`` HDF5 file, opened lazily in each worker.

h5py handles must not cross a fork: the file is opened on first access inside the process that
reads it (the DataLoader worker), never in ``__init__``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import h5py
import numpy as np
import torch
from torch.utils.data import Dataset

from handradar.data.hdf5 import read_attrs


class SpectrogramH5Dataset(Dataset):
    """Rows of a dataset file: ``{"spectrogram": (1, 64, 32), "label", "index"}`` plus, with
    ``with_skeleton``, ``"skeleton"`` (T, 2, 21, 3) and ``"hand_mask"`` (T, 2).

    indices: the subset of rows to expose (default: all), e.g. a few-shot split.
    label_map: optional remapping of stored labels (e.g. to a 5-class subset).
    """

    def __init__(self, path: str | Path, indices: Sequence[int] | None = None, *, with_skeleton: bool = False,
                 label_map: dict[int, int] | None = None) -> None:
        self.path = Path(path)
        attrs = read_attrs(self.path)  # validates the file up front, in the parent process
        self.classes = attrs["classes"]
        self.indices = np.arange(attrs["n"]) if indices is None else np.asarray(indices, dtype=np.int64)
        self.with_skeleton = with_skeleton
        self.label_map = label_map
        self._h5: h5py.File | None = None

    def __len__(self) -> int:
        return len(self.indices)

    def _file(self) -> h5py.File:
        if self._h5 is None:
            self._h5 = h5py.File(self.path, "r")
        return self._h5

    def labels(self) -> np.ndarray:
        with h5py.File(self.path, "r") as h5:
            labels = h5["labels"][()][self.indices]
        return np.asarray([self.label_map[int(v)] for v in labels]) if self.label_map else labels

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        h5 = self._file()
        row = int(self.indices[i])
        label = int(h5["labels"][row])
        if self.label_map is not None:
            label = self.label_map[label]
        item = {"spectrogram": torch.from_numpy(h5["spectrograms"][row][None]),
                "label": torch.tensor(label, dtype=torch.long), "index": torch.tensor(row)}
        if self.with_skeleton:
            item["skeleton"] = torch.from_numpy(h5["skeletons"][row])
            item["hand_mask"] = torch.from_numpy(h5["hand_mask"][row])
        return item

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_h5"] = None  # never pickle an open handle into a worker
        return state
