"""Per-bone motion features of a skeleton window: RadarWeightNet's input (Tang et al.), cached.

For every step t, hand h and bone k (all from the retargeted skeleton, bone midpoint = the
simulator's scattering centre, radar at the origin):

    visible_vertices       count of the bone's mesh vertices seen by the radar (0..422)
    rcs_m2                 cylinder RCS (handradar.sim.rcs.cylinder_rcs_m2) at the simulator's aspect
                           exponent (``rcs_exponent``, part of the cache key), m^2
    distance_m             |midpoint|, metres
    radial_velocity_m_s    d distance / dt, m/s, positive = receding
    radial_acceleration_m_s2  d^2 distance / dt^2, m/s^2

Derivatives are central differences in time (numpy.gradient on the true step times); across
untracked steps the distance is interpolated linearly while differentiating (no spike at a gap)
and those steps are zero in the output (all
features of an untracked hand are 0). ``facing`` counts (the denominator of the occlusion
fraction) come along.

Visibility is the expensive part (ray casting every step); results are cached in HDF5 files
named by :func:`handradar.provenance.config_hash` of the hand model, the radar wavelength, the
times and a digest of the skeleton arrays, written through :func:`handradar.atomic.atomic_path`.
Long computations are resumable: finished rows go to ``<cache>.partial`` (HDF5, attribute
``done``) and a rerun with the same key continues from there. Processes that need the same key at
once take turns on ``<cache>.lock``: one computes, the others then read its file.

Public API:

    FEATURE_NAMES (5 names above, feature axis order)
    HandModelConfig(retarget=True, hand_scale=1.0, sections=20, rings=21, backend="auto",
                    visibility_stride=2)        (conf/hand/default.yaml)
    HandModelConfig.joints(positions) -> retargeted joints (numpy (..., 21, 3))
    bone_features(positions (T, 2, 21, 3), times (T,), mask (T, 2), wavelength_m, cfg)
        -> BoneFeatures(features (T, 2, 19, 5) float32, facing (T, 2, 19) int32)
    cached_bone_features(positions (N, T, 2, 21, 3), times (T,), masks (N, T, 2), wavelength_m, cfg,
                         cache_dir, progress=False, chunk=16, n_jobs=1) -> BoneFeatures((N, T, 2, 19, 5), (N, T, 2, 19))
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import torch

from handradar.atomic import atomic_path, file_lock
from handradar.hand.mesh import bone_radii, default_template
from handradar.hand.model import HandModelConfig
from handradar.hand.skeleton import N_BONES
from handradar.hand.visibility import visibility
from handradar.provenance import array_digest, config_hash
from handradar.sim.scatterers import (  # the simulator's own definitions
        bone_geometry,
        bone_rcs_m2,
    )

FEATURE_NAMES = ("visible_vertices", "rcs_m2", "distance_m", "radial_velocity_m_s", "radial_acceleration_m_s2")
N_FEATURES = len(FEATURE_NAMES)
CACHE_FORMAT = "handradar.bone_features/3"  # 2: buried vertices neither facing nor visible; 3: RCS exponent in the key


@dataclass
class BoneFeatures:
    features: np.ndarray  # (..., T, 2, 19, 5) float32, FEATURE_NAMES order
    facing: np.ndarray  # (..., T, 2, 19) int32

    def visible_fraction(self) -> np.ndarray:
        """visible / facing vertices, (..., T, 2, 19) float32 in [0, 1] (0 where nothing faces)."""
        vis = self.features[..., 0]
        return np.divide(vis, self.facing, out=np.zeros(vis.shape, np.float32), where=self.facing > 0)


def _fill_untracked(x: np.ndarray, mask: np.ndarray, times: np.ndarray) -> np.ndarray:
    """x (T, 2, 19) with untracked steps filled linearly in time from the tracked ones (ends held)."""
    out = x.copy()
    for h in range(x.shape[1]):
        ok = mask[:, h]
        if ok.any() and not ok.all():
            for k in range(x.shape[2]):
                out[~ok, h, k] = np.interp(times[~ok], times[ok], x[ok, h, k])
    return out


def bone_features(positions: np.ndarray, times: np.ndarray, mask: np.ndarray, wavelength_m: float,
                  cfg: HandModelConfig | None = None, rcs_exponent: float = 1.0) -> BoneFeatures:
    """Features of one window (see module doc); positions (T, 2, 21, 3) metres, times (T,) seconds;
    ``rcs_exponent``: the simulator's cylinder RCS aspect exponent (handradar.sim.rcs), so that the
    network reads the RCS the simulator uses."""

    cfg = cfg or HandModelConfig()
    mask = np.asarray(mask, dtype=bool)
    times = np.asarray(times, dtype=np.float64)
    joints = cfg.joints(positions)
    vis = visibility(joints, mask, template=default_template(cfg.sections, cfg.rings), backend=cfg.backend,
                     stride=cfg.visibility_stride)
    mid, axis, length = bone_geometry(torch.as_tensor(joints))
    rcs = bone_rcs_m2(mid, axis, length, torch.as_tensor(bone_radii()), wavelength_m, float(rcs_exponent)).numpy()
    dist = np.linalg.norm(mid.numpy(), axis=-1)  # (T, 2, 19)
    m = mask[..., None] & np.ones(N_BONES, bool)
    if times.shape[0] >= 2 and mask.any():
        filled = _fill_untracked(dist, mask, times)
        vel = np.gradient(filled, times, axis=0)
        acc = np.gradient(vel, times, axis=0)
    else:
        vel = acc = np.zeros_like(dist)
    feats = np.stack([vis.visible.astype(np.float64), rcs, dist, vel, acc], axis=-1)
    feats[~m] = 0.0
    return BoneFeatures(feats.astype(np.float32), vis.facing)


def features_key(positions: np.ndarray, times: np.ndarray, masks: np.ndarray, wavelength_m: float,
                 cfg: HandModelConfig, rcs_exponent: float = 1.0) -> str:
    return config_hash(CACHE_FORMAT, cfg.key(), float(wavelength_m), float(rcs_exponent), array_digest(
        np.asarray(positions, np.float32), np.asarray(times, np.float64), np.asarray(masks, bool)))


def _read_cache(path: Path, key: str) -> BoneFeatures | None:
    """The cached features at ``path`` when it holds this format and key, else None."""
    if not path.is_file():
        return None
    with h5py.File(path, "r") as h5:
        if h5.attrs.get("format") == CACHE_FORMAT and h5.attrs.get("config_hash") == key:
            return BoneFeatures(h5["features"][()], h5["facing"][()])
    return None


def cached_bone_features(positions: np.ndarray, times: np.ndarray, masks: np.ndarray, wavelength_m: float,
                         cfg: HandModelConfig | None = None, cache_dir: str | Path | None = None,
                         *, rcs_exponent: float = 1.0, progress: bool = False, chunk: int = 16,
                         n_jobs: int = 1) -> BoneFeatures:
    """Features of N windows, read from / written to ``cache_dir/bone_features-<hash>.h5``.

    positions (N, T, 2, 21, 3), times (T,) shared by all rows, masks (N, T, 2). Without a
    cache_dir nothing is stored. ``n_jobs`` > 1 computes each block of ``chunk`` rows in that many
    processes (joblib); progress is saved after every block.
    """
    cfg = cfg or HandModelConfig()
    positions = np.asarray(positions, np.float32)
    masks = np.asarray(masks, bool)
    n, t = positions.shape[:2]
    if positions.shape[2:] != (2, 21, 3) or masks.shape != (n, t, 2) or np.shape(times) != (t,):
        raise ValueError(f"expected positions (N, T, 2, 21, 3), times (T,), masks (N, T, 2); found "
                         f"{positions.shape}, {np.shape(times)}, {masks.shape}")

    def rows(i0: int, i1: int, jobs: int = n_jobs) -> list[BoneFeatures]:
        if jobs > 1:
            from joblib import Parallel, delayed
            return Parallel(n_jobs=jobs)(delayed(bone_features)(positions[i], times, masks[i], wavelength_m, cfg,
                                                                  rcs_exponent) for i in range(i0, i1))
        return [bone_features(positions[i], times, masks[i], wavelength_m, cfg, rcs_exponent) for i in range(i0, i1)]

    if cache_dir is None:
        out = rows(0, n, jobs=1)
        return BoneFeatures(np.stack([r.features for r in out]) if out else np.zeros((0, t, 2, N_BONES, N_FEATURES), np.float32),
                            np.stack([r.facing for r in out]) if out else np.zeros((0, t, 2, N_BONES), np.int32))
    key = features_key(positions, times, masks, wavelength_m, cfg, rcs_exponent)
    path = Path(cache_dir) / f"bone_features-{key}.h5"
    cached = _read_cache(path, key)
    if cached is not None:
        return cached
    # One builder per key: a second process (another job of a sweep) waits here, then reads.
    with file_lock(path.with_name(path.name + ".lock")):
        cached = _read_cache(path, key)
        if cached is None:
            cached = _build_cache(path, key, (n, t), rows, chunk, progress)
    return cached


def _build_cache(path: Path, key: str, shape: tuple[int, int], rows: Callable[[int, int], list[BoneFeatures]],
                 chunk: int, progress: bool) -> BoneFeatures:
    """Compute the N rows (``rows(i0, i1)`` -> BoneFeatures per row) block by block into
    ``<path>.partial`` (resuming what it holds for this key), then write ``path`` atomically."""
    n, t = shape
    partial = path.with_name(path.name + ".partial")
    try:
        h5p = h5py.File(partial, "a" if partial.is_file() else "w")
    except OSError:  # a corrupt partial file from a hard kill: start over
        partial.unlink(missing_ok=True)
        h5p = h5py.File(partial, "w")
    with h5p:
        if h5p.attrs.get("config_hash") != key or "features" not in h5p:
            for k in list(h5p.keys()):
                del h5p[k]
            h5p.attrs["config_hash"] = key
            h5p.attrs["done"] = 0
            h5p.create_dataset("features", (n, t, 2, N_BONES, N_FEATURES), dtype="f4")
            h5p.create_dataset("facing", (n, t, 2, N_BONES), dtype="i4")
        blocks = range(int(h5p.attrs["done"]), n, chunk)
        if progress:
            from tqdm import tqdm
            blocks = tqdm(blocks, desc="bone features", unit="block")
        for i0 in blocks:
            i1 = min(n, i0 + chunk)
            block = rows(i0, i1)
            h5p["features"][i0:i1] = np.stack([r.features for r in block])
            h5p["facing"][i0:i1] = np.stack([r.facing for r in block])
            h5p.attrs["done"] = i1
            h5p.flush()
        feats, facing = h5p["features"][()], h5p["facing"][()]
    with atomic_path(path) as tmp:
        with h5py.File(tmp, "w") as h5:
            h5.attrs["format"] = CACHE_FORMAT
            h5.attrs["config_hash"] = key
            h5.attrs["feature_names"] = list(FEATURE_NAMES)
            h5.create_dataset("features", data=feats)
            h5.create_dataset("facing", data=facing)
    os.unlink(partial)
    return BoneFeatures(feats, facing)
