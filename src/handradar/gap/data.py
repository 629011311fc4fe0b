"""The rows a gap diagnosis works on: a ``handradar.dataset/1`` file in memory.

Public API:

    GapData: measured (N, 64, 32) float32, rows (handradar.gap.engine.RowSet), labels (N,),
             meta {field: (N,)}, radar, chain, path, range_mirror_db (N,) dB or None, read_options;
             .take(idx) -> GapData
    load_dataset(path) -> GapData       (FormatError naming the file if it cannot be simulated)
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import h5py
import numpy as np

from handradar.data.hdf5 import read_attrs, read_convention, read_meta_group
from handradar.errors import FormatError
from handradar.gap.engine import RowSet
from handradar.radar.chain import ChainConfig
from handradar.radar.config import RadarConfig


@dataclass
class GapData:
    measured: np.ndarray  # (N, doppler, columns) float32 in [0, 1]
    rows: RowSet  # skeleton windows, masks, times (s), visibility (filled in by the diagnosis if needed)
    labels: np.ndarray  # (N,) int64 gesture index
    meta: dict[str, np.ndarray]  # meta.json fields per row (no truth: the dataset has none)
    radar: RadarConfig
    chain: ChainConfig
    skeleton_rate_hz: float
    path: Path | None = None
    # ingest's range figure per row (dB; handradar.data.convention; None: the file has none) and the
    # options its rows were read with (iq_swap, doppler_flip): the sign-convention check of the rows reads them
    range_mirror_db: np.ndarray | None = None
    read_options: dict[str, bool] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.measured.shape[0])

    def take(self, idx: np.ndarray) -> GapData:
        idx = np.asarray(idx, dtype=np.int64)
        return replace(self, measured=self.measured[idx], rows=self.rows.take(idx), labels=self.labels[idx],
                       meta={k: v[idx] for k, v in self.meta.items()},
                       range_mirror_db=None if self.range_mirror_db is None else self.range_mirror_db[idx])


def load_dataset(path: str | Path) -> GapData:
    """Every row of a dataset file: spectrograms, skeleton windows, labels, meta, radar and chain (the
    diagnosis's own check, handradar.gap.folds.check_rows, says whether they are enough)."""
    path = Path(path)
    attrs = read_attrs(path)
    radar, chain = attrs.get("radar"), attrs.get("chain")
    if radar is None or chain is None or "skeleton_rate_hz" not in attrs:
        raise FormatError(path, "needs the attributes radar_cfg, chain and skeleton_rate_hz to simulate its rows")
    with h5py.File(path, "r") as h5:
        measured = h5["spectrograms"][()].astype(np.float32)
        labels = h5["labels"][()].astype(np.int64)
        skeletons = h5["skeletons"][()].astype(np.float32)
        masks = h5["hand_mask"][()].astype(bool) if "hand_mask" in h5 else np.abs(skeletons).sum(axis=(-2, -1)) > 0
    rate = float(attrs["skeleton_rate_hz"])
    times = np.arange(skeletons.shape[1]) / rate
    if measured.shape[1:] != (chain.n_doppler, chain.n_columns):
        raise FormatError(path, f"spectrograms {measured.shape[1:]} do not match the chain's "
                                f"({chain.n_doppler}, {chain.n_columns})")
    return GapData(measured, RowSet(skeletons, masks, times), labels, read_meta_group(path), radar, chain, rate, path,
                   *read_convention(path))
