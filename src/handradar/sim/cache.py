"""Cache of the network-independent per-slot signals (the simulator's expensive part).

The per-slot range profiles (B, 39, F, L, Ch, bins) of a dataset do not depend on RadarWeightNet,
so they are computed once and stored: float16 real/imag pairs scaled by a per-row float32 factor
(the row's largest |real| or |imag|), i.e. ~5e-4 relative precision, far inside the chain's 30 dB
floor. 39 x 2048 chirps x 8 bins x 2 x 2 bytes = 2.6 MB per example (default radar); each slot of
a row is one uncompressed HDF5 chunk, written only when non-zero, so the 19 slots of an untracked
hand cost nothing on disk. ``active`` (N, 38) records the non-zero bone slots, so that a batch of
one-hand examples skips the other hand (Simulator.combine(..., active=...)).

The file is named by :func:`handradar.provenance.config_hash` of the radar, the chain, the
simulator's settings and effects (with their values), and a digest of the input arrays; it is
written through :func:`handradar.atomic.atomic_path`.

Public API:

    slot_profiles_key(sim, skeletons, masks, times=None, visibility=None) -> str
    cache_slot_profiles(sim, skeletons (N, T, 2, 21, 3), masks (N, T, 2), cache_dir, *, times=None,
                        visibility=None (N, T, 2, 19), progress=False) -> Path
    SlotProfileCache(path)   (opens lazily; safe to hand to DataLoader workers)
        .n, .key;  .load(rows) -> (packed (B, 39, F, L, Ch, bins, 2) float16, scale (B,) float32,
                                   active (B, 38) bool)
        .profiles(rows) -> complex64 (B, 39, F, L, Ch, bins)    (unpacked, scaled)
    pack(profiles complex) -> (packed float16, scale);  unpack(packed, scale) -> complex64
    cache_dataset(dataset.h5, sim, cache_dir, progress=False, n_jobs=1) -> DatasetCaches(features
        BoneFeatures (N, T, 2, 19, 5), masks (N, T, 2), times (T,), profiles SlotProfileCache): both caches
        of a handradar.dataset/1 file (features first: their visibility feeds the occlusion effect)
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import h5py
import numpy as np
import torch

from handradar.atomic import atomic_path
from handradar.data.hdf5 import read_attrs, read_rows
from handradar.errors import FormatError
from handradar.provenance import array_digest, config_hash
from handradar.sim.features import BoneFeatures, cached_bone_features
from handradar.sim.profiles import N_ALL_SLOTS
from handradar.sim.scatterers import N_SLOTS

CACHE_FORMAT = "handradar.slot_profiles/2"  # 2: keyed by Simulator.key()


def pack(profiles: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Complex (B, ...) -> float16 real view (B, ..., 2) in [-1, 1] and the per-row scale (B,)."""
    real = torch.view_as_real(profiles.detach()).to(torch.float32)
    scale = real.abs().flatten(1).amax(1).clamp_min(1e-30)
    return (real / scale.reshape(-1, *[1] * (real.dim() - 1))).to(torch.float16), scale


def unpack(packed: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`pack`: complex64."""
    real = packed.to(torch.float32) * scale.reshape(-1, *[1] * (packed.dim() - 1)).to(torch.float32)
    return torch.view_as_complex(real.contiguous())


def slot_profiles_key(sim, skeletons: np.ndarray, masks: np.ndarray, times: np.ndarray | None = None,
                      visibility: np.ndarray | None = None, arms: np.ndarray | None = None) -> str:
    arrays = [np.asarray(skeletons, np.float32), np.asarray(masks, bool)]
    if arms is not None:  # appended only when present: the keys of armless sources hold
        arrays.append(np.asarray(arms, np.float32))
    if times is not None:
        arrays.append(np.asarray(times, np.float64))
    if visibility is not None:
        arrays.append(np.asarray(visibility, np.float32))
    return config_hash(CACHE_FORMAT, sim.key(), times is None, visibility is None, array_digest(*arrays))


@torch.no_grad()
def cache_slot_profiles(sim, skeletons: np.ndarray, masks: np.ndarray, cache_dir: str | Path, *,
                        times: np.ndarray | None = None, visibility: np.ndarray | None = None,
                        arms: np.ndarray | None = None, progress: bool = False) -> Path:
    """Compute (unless present) and store the slot profiles of N windows; returns the file path.

    One window at a time: a batch would simulate the absent hand of its one-hand rows whenever
    another row tracks both (twice the work), and its temporaries outgrow the CPU caches (measured:
    7 against 15 ms per window in batches of 8). Each slot is its own uncompressed HDF5 chunk and
    only non-zero slots are written, so an untracked hand costs no disk and no compression time
    (lzf on whole rows took longer than the simulation itself)."""
    skeletons = np.asarray(skeletons, np.float32)
    masks = np.asarray(masks, bool)
    key = slot_profiles_key(sim, skeletons, masks, times, visibility, arms)
    path = Path(cache_dir) / f"slot_profiles-{key}.h5"
    if path.is_file():
        with h5py.File(path, "r") as h5:
            if h5.attrs.get("format") == CACHE_FORMAT and h5.attrs.get("config_hash") == key:
                return path
    n = skeletons.shape[0]
    t = None if times is None else torch.as_tensor(times, dtype=torch.float64)
    with atomic_path(path) as tmp, h5py.File(tmp, "w") as h5:
        h5.attrs["format"] = CACHE_FORMAT
        h5.attrs["config_hash"] = key
        ds = scales = act = None
        rows = range(n)
        if progress:
            from tqdm import tqdm
            rows = tqdm(rows, desc="slot profiles", unit="row")
        for i in rows:
            vis = None if visibility is None else torch.as_tensor(visibility[i:i + 1])
            prof = sim.slot_profiles(torch.as_tensor(skeletons[i:i + 1]), torch.as_tensor(masks[i:i + 1]),
                                     times=t, visibility=vis,
                                     arm=None if arms is None else torch.as_tensor(arms[i:i + 1]))
            packed, scale = pack(prof)
            if ds is None:
                shape = tuple(packed.shape[2:])
                ds = h5.create_dataset("profiles", (n, N_ALL_SLOTS, *shape), dtype="f2", chunks=(1, 1, *shape),
                                       fillvalue=0.0)
                scales = h5.create_dataset("scale", (n,), dtype="f4")
                act = h5.create_dataset("active", (n, N_SLOTS), dtype=bool)
            nonzero = packed[0].flatten(1).abs().amax(1) > 0  # (39,)
            slabs = packed[0].numpy()
            for k in np.flatnonzero(nonzero.numpy()):  # unwritten chunks read back as the fill value 0
                ds.id.write_direct_chunk((i, int(k)) + (0,) * len(shape), np.ascontiguousarray(slabs[k]).tobytes())
            scales[i] = float(scale[0])
            act[i] = (prof[0, :N_SLOTS].abs().flatten(1).amax(-1) > 0).numpy()
    return path


class SlotProfileCache:
    """Read side of a slot-profile cache file (opened on first access, per process)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        with h5py.File(self.path, "r") as h5:
            if h5.attrs.get("format") != CACHE_FORMAT:
                raise FormatError(self.path, f"not a slot-profile cache (format {h5.attrs.get('format')!r})")
            self.key = str(h5.attrs["config_hash"])
            self.n = int(h5["profiles"].shape[0]) if "profiles" in h5 else 0
        self._h5: h5py.File | None = None

    def _file(self) -> h5py.File:
        if self._h5 is None:
            self._h5 = h5py.File(self.path, "r")
        return self._h5

    def load(self, rows) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        rows = np.atleast_1d(np.asarray(rows, dtype=np.int64))
        if rows.size and (rows.min() < 0 or rows.max() >= self.n):
            raise IndexError(f"{self.path}: rows must be in [0, {self.n}), found {rows.min()}..{rows.max()}")
        uniq, inv = np.unique(rows, return_inverse=True)
        h5 = self._file()
        return (torch.from_numpy(read_rows(h5["profiles"], uniq)[inv]), torch.from_numpy(h5["scale"][()][uniq][inv]),
                torch.from_numpy(h5["active"][()][uniq][inv]))

    def profiles(self, rows) -> torch.Tensor:
        packed, scale, _ = self.load(rows)
        return unpack(packed, scale)

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_h5"] = None
        return state


@dataclass
class DatasetCaches:
    """Everything RadarWeightNet training needs from a dataset, network-independent and cached.

    features: (N, T, 2, 19, 5) and facing counts (handradar.sim.features.BoneFeatures)
    masks: (N, T, 2) bool; times: (T,) seconds; profiles: the slot-profile cache of the N rows.
    """

    features: BoneFeatures
    masks: np.ndarray
    times: np.ndarray
    profiles: SlotProfileCache


def cache_dataset(dataset: str | Path, sim, cache_dir: str | Path, *, progress: bool = False,
                  n_jobs: int = 1) -> DatasetCaches:
    """Bone features and slot profiles of every row of a ``handradar.dataset/1`` file.

    The simulator must match the file's radar, chain and skeleton rate (a FormatError says which
    differs). Visibility fractions from the features feed the occlusion effect when it is selected.
    """
    dataset = Path(dataset)
    attrs = read_attrs(dataset)
    radar, chain = attrs.get("radar"), attrs.get("chain")
    if radar is None or chain is None or "skeleton_rate_hz" not in attrs:
        raise FormatError(dataset, "needs the attributes radar_cfg, chain and skeleton_rate_hz to simulate its rows")
    if replace(radar, n_frames=0) != replace(sim.radar, n_frames=0):
        raise FormatError(dataset, "its radar configuration differs from the simulator's")
    if chain != sim.chain:
        raise FormatError(dataset, f"its chain {chain} differs from the simulator's {sim.chain}")
    if abs(float(attrs["skeleton_rate_hz"]) - sim.skeleton_rate_hz) > 1e-9:
        raise FormatError(dataset, f"skeleton rate {attrs['skeleton_rate_hz']} Hz differs from the simulator's "
                                   f"{sim.skeleton_rate_hz} Hz")
    with h5py.File(dataset, "r") as h5:
        skeletons = h5["skeletons"][()]
        masks = h5["hand_mask"][()] if "hand_mask" in h5 else np.abs(skeletons).sum(axis=(-2, -1)) > 0
    times = np.arange(skeletons.shape[1]) / sim.skeleton_rate_hz
    feats = cached_bone_features(skeletons, times, masks, sim.radar.wavelength_m, sim.hand, cache_dir,
                                 rcs_exponent=sim.rcs_exponent, progress=progress, n_jobs=n_jobs)
    needs_visibility = any(e.name == "occlusion" for e in sim.effects)
    path = cache_slot_profiles(sim, skeletons, masks, cache_dir,
                               visibility=feats.visible_fraction() if needs_visibility else None,
                               progress=progress)
    return DatasetCaches(feats, masks, times, SlotProfileCache(path))
