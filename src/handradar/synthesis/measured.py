"""Synthetic rows for a measured dataset without skeletons, and the unpaired fit of what its manifest leaves unknown.

Synthesis (:func:`synthesize_measured`): the dataset's classes become skeletons through their
motions (the ``motions`` source, handradar.hand.motions), simulated by the paper's model with a
radar whose frame-based Doppler map has the dataset's grid (handradar.data.measured.synthesis_radar).

The fit (:func:`fit_unknowns`, docs/datasets.md#measured-radar-datasets): no measured row has a
skeleton, so nothing is paired. For every candidate of the unknowns the synthetic rows' class-mean
images (objective ``means``), or class-mean and class-spread images (per-pixel standard deviation,
``moments``), are compared with the measured rows': 1 - SSIM averaged over the images (torchmetrics
SSIM, ``data_range=1.0``). The spread is what tells a noise floor's texture (its looks) apart from its
level. Two unknowns cost
no new simulation and are exact:

- the dB floor: rows synthesised with a deep floor D0 are re-floored at any D <= D0 by
  ``clip((x D0 - (D0 - D)) / D, 0, 1)`` (a spectrogram in [0, 1] is ``(dB - peak + D0) / D0``);
- which end of the Doppler axis is approaching: a mirror about the zero row.

A receiver noise floor (its level and looks, :func:`add_noise_floor`) is added to the simulated rows
without a new simulation either.

The loop period (v_max), the time per column and the chirps a frame (zero-padded to the Doppler
bins: fewer chirps widen every Doppler line) need a simulation each. The uncertainty is a
bootstrap over the measured rows (classes resampled within themselves): the share of resamples that
choose each candidate value, and the 2.5-97.5 % range of the chosen values.
"""

from __future__ import annotations

import itertools
import json
import logging
import shutil
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import h5py
import numpy as np

from handradar.atomic import atomic_path
from handradar.data.hdf5 import read_attrs
from handradar.data.measured import Manifest, dataset_chain, synthesis_radar
from handradar.errors import FormatError
from handradar.metrics import per_example_ssim
from handradar.provenance import config_hash
from handradar.synthesis.providers import synthesize_source

log = logging.getLogger(__name__)

DEEP_FLOOR_DB = 60.0  # the floor rows are synthesised at before the fit re-floors them
OBJECTIVES = {  # what fit_unknowns compares, 1 - SSIM averaged over its images
    "means": "1 - SSIM of class-mean images, mean over classes",
    "moments": "1 - SSIM of class-mean and class-spread images, mean over both and over classes",
}


def mirror_doppler(x: np.ndarray) -> np.ndarray:
    """Spectrograms (..., doppler, columns) with the Doppler axis mirrored about the zero row ``doppler // 2``."""
    n = x.shape[-2]
    return np.roll(x[..., ::-1, :], 1 - n % 2, axis=-2)


def refloor(x: np.ndarray, from_db: float, to_db: float) -> np.ndarray:
    """Spectrograms in [0, 1] with a floor ``from_db`` below their peak, re-expressed with the floor at ``to_db`` (<= from_db)."""
    if to_db > from_db:
        raise ValueError(f"cannot lower a {from_db:g} dB floor to {to_db:g} dB: what lay below it is lost")
    return np.clip((x * from_db - (from_db - to_db)) / to_db, 0.0, 1.0).astype(np.float32)


def measured_manifest(real_path: str | Path) -> tuple[Manifest, tuple[int, int]]:
    """The manifest a measured dataset file was built from, and its (doppler, columns) grid."""
    attrs = read_attrs(real_path)
    if attrs.get("skeletons") != "none" or "manifest" not in attrs:
        raise FormatError(real_path, "not a measured dataset (data=measured data.manifest=FILE builds one)")
    return Manifest.from_dict(json.loads(attrs["manifest"]), Path(real_path)), (attrs["chain"].n_doppler,
                                                                                attrs["chain"].n_columns)


def add_noise_floor(x: np.ndarray, noise_db: float, rng: np.random.Generator, looks: int = 1) -> np.ndarray:
    """Rows at a ``DEEP_FLOOR_DB`` floor with receiver noise added, at the same floor again.

    Each row's power relative to its peak, ``10^((x D0 - D0) / 10)``, gains white noise of mean power
    ``10^(noise_db / 10)`` per pixel (``noise_db`` < 0: below the noise-free peak). A pixel's noise is the power of
    ``looks`` independent complex Gaussian cells averaged (range bins or antennas collapsed into one Doppler
    row): gamma-distributed with shape ``looks`` and mean 1; ``looks`` = 1 is the exponential power of one cell.
    The row is then rescaled to its new peak (handradar.radar.chain power_to_unit)."""
    if int(looks) < 1:
        raise ValueError(f"noise looks must be a positive count, found {looks}")
    d0 = DEEP_FLOOR_DB
    noise = rng.gamma(float(int(looks)), 1.0 / int(looks), size=x.shape)
    power = 10.0 ** ((x.astype(np.float64) * d0 - d0) / 10.0) + 10.0 ** (noise_db / 10.0) * noise
    db = 10.0 * np.log10(power)
    top = db.max(axis=(-2, -1), keepdims=True)
    return np.clip((db - top + d0) / d0, 0.0, 1.0).astype(np.float32)


FINISH_KEYS = ("noise_db", "noise_looks", "dynamic_range_db", "approaching")  # what finish_rows applies


def finish_rows(x: np.ndarray, values: Mapping[str, float | str | None], seed: int) -> np.ndarray:
    """Rows simulated at a ``DEEP_FLOOR_DB`` floor, approaching high, as ``values`` says the dataset shows them: receiver
    noise (``noise_db``, None: none; ``noise_looks`` cells averaged per pixel, default 1), the dB floor
    (``dynamic_range_db``), the approaching end (``approaching``)."""
    if values.get("noise_db") is not None:
        x = add_noise_floor(x, float(values["noise_db"]), np.random.default_rng([int(seed), 7]),
                            int(values.get("noise_looks") or 1))
    if values.get("dynamic_range_db") is not None:
        x = refloor(x, DEEP_FLOOR_DB, float(values["dynamic_range_db"]))
    return mirror_doppler(x) if values.get("approaching", "high") == "low" else x


def synthesize_measured(real_path: str | Path, values: Mapping[str, float | str | None], *, per_class: int, seed: int,
                        cache_dir: str | Path, sim: Mapping | None = None) -> Path:
    """Synthetic rows of a measured dataset's classes, cached by everything that makes them. ``values`` holds the
    manifest's unknowns: ``v_max_m_s``, ``frame_period_s`` and ``chirps_per_frame`` set the simulated radar;
    ``noise_db``, ``noise_looks``, ``dynamic_range_db`` and ``approaching`` are applied to the rows simulated at a deep
    floor (:func:`finish_rows`)."""
    m, shape = measured_manifest(real_path)
    radar = synthesis_radar(m, shape, values)
    chain = replace(dataset_chain(m, shape, radar.n_loops), dynamic_range_db=DEEP_FLOOR_DB)
    source = {"name": "motions", "classes": m.classes, "per_class": int(per_class), "seed": int(seed),
              "duration_s": shape[1] * radar.frame_period_s, "ranges": {k: list(v) for k, v in m.motion_ranges.items()}}
    # measured/2: rendered by Simulator.render_rows (no float16 slot-profile cache in between)
    out = Path(cache_dir) / f"measured-synth-{config_hash(source, radar, chain, dict(sim or {}), 'measured/2')}.h5"
    if not out.is_file():
        log.info("synthesising %d rows per class of %d classes (v_max %.2f m/s, %.1f ms per column, %d chirps a frame)",
                 per_class, len(m.classes), radar.max_velocity_m_s, radar.frame_period_s * 1e3, radar.n_loops)
        synthesize_source(source, out, radar=radar, chain=chain, sim=dict(sim or {}) or None,
                          cache_dir=Path(cache_dir) / "profiles", progress=False)
    finish = {k: values.get(k) for k in FINISH_KEYS}
    if finish["dynamic_range_db"] is not None and float(finish["dynamic_range_db"]) == DEEP_FLOOR_DB:
        finish["dynamic_range_db"] = None  # the simulated floor already
    if finish["noise_db"] is None:
        finish["noise_looks"] = None  # no noise: its looks change nothing
    if all(v in (None, "high") for v in finish.values()):
        return out
    finished = out.with_name(f"{out.stem}-{config_hash(finish, seed)}.h5")
    if not finished.is_file():
        with atomic_path(finished) as tmp:
            shutil.copyfile(out, tmp)
            with h5py.File(tmp, "r+") as h5:
                h5["spectrograms"][...] = finish_rows(h5["spectrograms"][()], finish, seed)
                h5.attrs["finish"] = json.dumps(finish)
    return finished


def class_moments(x: np.ndarray, y: np.ndarray, n_classes: int, objective: str = "means") -> np.ndarray:
    """Each class's mean image (n_classes, doppler, columns), then, for ``objective`` "moments", its per-pixel
    standard deviation (2 n_classes images: the spread tells a noise floor's texture apart from its level); a class
    without rows is an error."""
    if objective not in OBJECTIVES:
        raise ValueError(f"unknown fit objective {objective!r}; expected one of {sorted(OBJECTIVES)}")
    counts = np.bincount(y, minlength=n_classes)
    if counts.min() == 0:
        raise ValueError(f"class {int(np.argmin(counts))} has no row to take a mean of")
    means = [np.stack([x[y == c].mean(axis=0) for c in range(n_classes)])]
    spreads = [np.stack([x[y == c].std(axis=0) for c in range(n_classes)])] if objective == "moments" else []
    return np.concatenate(means + spreads)


@dataclass
class UnknownsFit:
    """The chosen values, every candidate's objective, and the bootstrap's verdict on each unknown."""

    values: dict[str, float | str]
    candidates: list[dict]          # {unknown: value, ..., "gap": objective}
    shares: dict[str, dict]         # unknown -> {candidate value: share of bootstrap resamples choosing it}
    ranges: dict[str, list]         # numeric unknown -> [2.5 %, 97.5 %] of the bootstrap's chosen values
    n_rows: int
    objective: str = "means"
    n_boot: int = 0                 # resamples behind shares and ranges; 0: the uncertainty could not be estimated

    @classmethod
    def from_dict(cls, d: Mapping) -> UnknownsFit:
        """The fit :meth:`as_dict` wrote (the cached ``measured-fit-<hash>.json``)."""
        return cls(**{k: d[k] for k in ("values", "candidates", "shares", "ranges", "n_rows", "n_boot")},
                   objective=next(k for k, v in OBJECTIVES.items() if v == d.get("objective", OBJECTIVES["means"])))

    def as_dict(self) -> dict:
        return {"values": self.values, "candidates": self.candidates, "shares": self.shares, "ranges": self.ranges,
                "n_rows": self.n_rows, "objective": OBJECTIVES[self.objective], "n_boot": self.n_boot}

    def summary(self) -> str:
        if not self.n_boot:
            return ("; ".join(f"{k} {v}" for k, v in self.values.items()) +
                    " (uncertainty not estimated: a class has fewer than 2 rows to resample)")
        parts = []
        for k, v in self.values.items():
            share = self.shares[k].get(str(v), 0.0)
            rng = f" [{self.ranges[k][0]:g}, {self.ranges[k][1]:g}]" if k in self.ranges else ""
            parts.append(f"{k} {v}{rng} (chosen by {share:.0%} of resamples)")
        return "; ".join(parts)


def fit_unknowns(real_x: np.ndarray, real_y: np.ndarray, n_classes: int,
                 simulate: Callable[[dict], tuple[np.ndarray, np.ndarray] | None],
                 grid: Mapping[str, Sequence], *, n_boot: int = 200, boot_candidates: int = 16,
                 seed: int = 0, objective: str = "means") -> UnknownsFit:
    """Choose the unknowns whose synthetic class means (and spreads) are closest to the measured ones (module docstring).

    simulate({v_max_m_s, frame_period_s, chirps_per_frame}) -> (x, y): synthetic rows at a floor of
    ``DEEP_FLOOR_DB``, approaching high; None where that radar is no candidate (a frame too short for its chirps).
    grid: candidate lists for ``v_max_m_s``, ``frame_period_s``, ``dynamic_range_db`` (each <= DEEP_FLOOR_DB),
    ``approaching`` (``high`` / ``low``) and optionally ``chirps_per_frame`` (None: as many as Doppler bins),
    ``noise_db`` (None: no noise) and ``noise_looks`` (default 1); a single-value list fixes that unknown. The
    bootstrap re-ranks the ``boot_candidates`` best candidates of the full fit; it is skipped (``n_boot`` 0 in the
    result: no uncertainty) where a class has fewer than 2 rows, whose every resample is the same rows.
    ``objective``: :data:`OBJECTIVES`.
    """
    optional = {"chirps_per_frame": [None], "noise_db": [None], "noise_looks": [1]}
    names = ("v_max_m_s", "frame_period_s", "chirps_per_frame", "noise_db", "noise_looks", "dynamic_range_db",
             "approaching")
    missing = [k for k in names if not grid.get(k) and k not in optional]
    if missing:
        raise ValueError(f"the fit needs candidates for {missing[0]}")
    g = {k: list(grid.get(k) or optional[k]) for k in names}
    combos, synth_moments = [], []
    for v_max, frame, chirps in itertools.product(g["v_max_m_s"], g["frame_period_s"], g["chirps_per_frame"]):
        radar = {"v_max_m_s": float(v_max), "frame_period_s": float(frame),
                 "chirps_per_frame": None if chirps is None else int(chirps)}
        made = simulate(radar)
        if made is None:
            continue
        x, y = made
        for noise, looks, floor, approaching in itertools.product(g["noise_db"], g["noise_looks"],
                                                                  g["dynamic_range_db"], g["approaching"]):
            if noise is None and looks != g["noise_looks"][0]:
                continue  # without noise its looks change nothing: one candidate
            values = {**radar, "noise_db": noise, "noise_looks": int(looks), "dynamic_range_db": float(floor),
                      "approaching": str(approaching)}
            combos.append(values)
            synth_moments.append(class_moments(finish_rows(x, values, seed), y, n_classes, objective))
    if not combos:
        raise ValueError("no candidate of the grid could be simulated")
    synth_moments = np.stack(synth_moments)  # (combos, classes or 2 classes, doppler, columns)

    def objectives(real_moments: np.ndarray, which: np.ndarray) -> np.ndarray:
        flat = np.broadcast_to(real_moments, synth_moments[which].shape).reshape(-1, *real_moments.shape[-2:])
        s = per_example_ssim(flat, synth_moments[which].reshape(-1, *real_moments.shape[-2:])).reshape(len(which), -1)
        return 1.0 - s.mean(axis=1)

    gaps = objectives(class_moments(real_x, real_y, n_classes, objective), np.arange(len(combos)))
    best = int(np.argmin(gaps))
    # the resamples re-rank the best candidates only: SSIM costs ~9 ms a pair on one core, and a candidate far
    # behind on all rows is not chosen by a resample of them
    contenders = np.argsort(gaps, kind="stable")[:boot_candidates]
    rng = np.random.default_rng(seed)
    members = [np.flatnonzero(real_y == c) for c in range(n_classes)]
    if min(len(m) for m in members) < 2:
        n_boot = 0
    chosen = []
    for _ in range(n_boot):
        rows = np.concatenate([rng.choice(m, size=len(m)) for m in members])
        resampled = class_moments(real_x[rows], real_y[rows], n_classes, objective)
        chosen.append(int(contenders[np.argmin(objectives(resampled, contenders))]))
    shares: dict[str, dict] = {k: {} for k in names} if chosen else {}
    for i in chosen:
        for k in names:
            key = str(combos[i][k])
            shares[k][key] = shares[k].get(key, 0.0) + 1.0 / n_boot
    ranges = {k: [float(np.percentile([combos[i][k] for i in chosen], q)) for q in (2.5, 97.5)]
              for k in names if chosen and k != "approaching" and all(combos[i][k] is not None for i in chosen)}
    candidates = [{**c, "gap": float(g)} for c, g in zip(combos, gaps)]
    return UnknownsFit(values=dict(combos[best]), candidates=candidates, shares=shares, ranges=ranges,
                       n_rows=int(len(real_y)), objective=objective, n_boot=int(n_boot))
