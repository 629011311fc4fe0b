"""The rows a gap diagnosis works on (a ``handradar.dataset/1`` file in memory) and its split.

Public API:

    GapData: measured (N, 64, 32) float32, rows (handradar.gap.engine.RowSet), labels (N,),
             meta {field: (N,)}, radar, chain, path;  .take(idx) -> GapData
    load_dataset(path) -> GapData       (FormatError naming the file if it cannot be simulated)
    stratified_split(labels, calibration_fraction, seed) -> (calibration idx, evaluation idx)
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import h5py
import numpy as np

from handradar.data.hdf5 import read_attrs, read_meta_group
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

    def __len__(self) -> int:
        return int(self.measured.shape[0])

    def take(self, idx: np.ndarray) -> GapData:
        idx = np.asarray(idx, dtype=np.int64)
        return replace(self, measured=self.measured[idx], rows=self.rows.take(idx), labels=self.labels[idx],
                       meta={k: v[idx] for k, v in self.meta.items()})


def load_dataset(path: str | Path) -> GapData:
    """Every row of a dataset file: spectrograms, skeleton windows, labels, meta, radar and chain."""
    path = Path(path)
    attrs = read_attrs(path)
    radar, chain = attrs.get("radar"), attrs.get("chain")
    if radar is None or chain is None or "skeleton_rate_hz" not in attrs:
        raise FormatError(path, "needs the attributes radar_cfg, chain and skeleton_rate_hz to simulate its rows")
    if attrs["n"] < 2:
        raise FormatError(path, f"a gap diagnosis needs at least 2 rows, found {attrs['n']}")
    with h5py.File(path, "r") as h5:
        measured = h5["spectrograms"][()].astype(np.float32)
        labels = h5["labels"][()].astype(np.int64)
        skeletons = h5["skeletons"][()].astype(np.float32)
        masks = h5["hand_mask"][()].astype(bool) if "hand_mask" in h5 else np.abs(skeletons).sum(axis=(-2, -1)) > 0
    rate = float(attrs["skeleton_rate_hz"])
    times = np.arange(skeletons.shape[1]) / rate
    if measured.shape[1:] != (chain.stft_len, chain.n_columns):
        raise FormatError(path, f"spectrograms {measured.shape[1:]} do not match the chain's "
                                f"({chain.stft_len}, {chain.n_columns})")
    return GapData(measured, RowSet(skeletons, masks, times), labels, read_meta_group(path), radar, chain, rate, path)


def stratified_split(labels: np.ndarray, calibration_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Disjoint calibration / evaluation rows, seeded, the same fraction of every class in each.

    A class of n >= 2 rows gives round(fraction * n) rows (at least 1, at most n - 1) to calibration;
    a class of one row goes to the split that is further below its target size.
    """
    if not 0.0 < calibration_fraction < 1.0:
        raise ValueError(f"calibration_fraction must be in (0, 1), found {calibration_fraction}")
    labels = np.asarray(labels)
    rng = np.random.default_rng(seed)
    cal: list[int] = []
    ev: list[int] = []
    singles: list[int] = []
    for c in np.unique(labels):
        rows = rng.permutation(np.flatnonzero(labels == c))
        if rows.size == 1:
            singles.append(int(rows[0]))
            continue
        k = int(np.clip(round(calibration_fraction * rows.size), 1, rows.size - 1))
        cal.extend(rows[:k].tolist())
        ev.extend(rows[k:].tolist())
    for r in rng.permutation(np.asarray(singles, dtype=np.int64)).tolist():
        n = len(cal) + len(ev) + 1
        (cal if len(cal) < calibration_fraction * n else ev).append(int(r))
    if not cal or not ev:
        raise ValueError(f"{labels.size} rows cannot be split into calibration and evaluation rows")
    return np.sort(np.asarray(cal, dtype=np.int64)), np.sort(np.asarray(ev, dtype=np.int64))
