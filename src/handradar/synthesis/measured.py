"""Synthetic rows for a measured dataset without skeletons, and the unpaired fit of what its manifest leaves unknown.

Synthesis (:func:`synthesize_measured`): the dataset's classes become skeletons through their
motions (the ``motions`` source, handradar.hand.motions), simulated by the paper's model with a
radar whose frame-based Doppler map has the dataset's grid (:func:`synthesis_radar`) and the dataset's
clutter filter, Doppler FFT and range handling, in dB at a deep floor; then finished (:func:`finish_rows`)
by the rest of its processing.

The fit (:func:`fit_unknowns`, docs/datasets.md#measured-radar-datasets): no measured row has a
skeleton, so nothing is paired. For every candidate of the unknowns (handradar.data.unknowns) the synthetic
rows' class-mean images (objective ``means``), or class-mean and class-spread images (per-pixel standard
deviation, ``moments``), are compared with the measured rows': 1 - SSIM averaged over the images (torchmetrics
SSIM, ``data_range=1.0``). The spread is what tells a noise floor's texture (its looks) apart from its
level. The unknowns that are not ``simulated`` cost no new simulation: rows synthesised at a deep floor D0
(a spectrogram in [0, 1] is ``(dB - peak + D0) / D0``) are power relative to their peak down to D0, to which
receiver noise (its level and looks) is added and the chain's scaling is applied (the dB floor, linear or dB,
magnitude or power, the normalisation); which end of the Doppler axis is approaching is a mirror about the
zero row.

The loop period (v_max), the time per column and the chirps a frame (zero-padded to the Doppler
bins: fewer chirps widen every Doppler line) need a simulation each, as does each candidate of the motions'
shared draws (speed, tremor, angle, distance, hand size: :func:`motion_ranges`), searched one at a time after them
(and the radar again where they moved). The uncertainty is a bootstrap over the measured rows and the synthetic
ones (classes resampled within themselves): the share of resamples that choose each candidate value, and the
2.5-97.5 % range of the chosen values. A numeric value chosen at the edge of its grid is reported as such
(:func:`grid_edges`), with how to widen the grid.
"""

from __future__ import annotations

import itertools
import json
import logging
import shutil
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import h5py
import numpy as np

import torch

from handradar.atomic import atomic_path
from handradar.data.datasets import load_arrays
from handradar.data.measured import PROCESSING, RADAR_FIELDS, Manifest, dataset_chain, measured_manifest
from handradar.data.unknowns import MOTION, UNKNOWN, UNKNOWNS
from handradar.errors import FormatError
from handradar.hand.motions import DEFAULT_RANGES, library_key
from handradar.metrics import per_example_ssim
from handradar.provenance import config_hash
from handradar.radar.chain import ChainConfig, power_to_unit
from handradar.radar.config import RadarConfig
from handradar.synthesis.providers import synthesize_source

log = logging.getLogger(__name__)

DEEP_FLOOR_DB = 60.0  # the floor rows are synthesised at before the fit re-floors them
FIT_VERSION = 4  # raised whenever fit_unknowns chooses or reports otherwise (2: motion unknowns; 3: passes; 4: the
# radar's resamples redraw the synthetic rows): no stale cached fit
PRIOR_KEPT_BELOW = 0.975  # a motion unknown leaves its prior only when its best beats it in this share of resamples
OBJECTIVES = {  # what fit_unknowns compares, 1 - SSIM averaged over its images
    "means": "1 - SSIM of class-mean images, mean over classes",
    "moments": "1 - SSIM of class-mean and class-spread images, mean over both and over classes",
}


def mirror_doppler(x: np.ndarray) -> np.ndarray:
    """Spectrograms (..., doppler, columns) with the Doppler axis mirrored about the zero row ``doppler // 2``."""
    n = x.shape[-2]
    return np.roll(x[..., ::-1, :], 1 - n % 2, axis=-2)


def noisy_power(x: np.ndarray, noise_db: float | None, rng: np.random.Generator, looks: int = 1) -> np.ndarray:
    """Rows at a ``DEEP_FLOOR_DB`` floor as power relative to each row's peak, ``10^((x D0 - D0) / 10)``, with white
    receiver noise of mean power ``10^(noise_db / 10)`` a pixel added (``noise_db`` < 0: below the noise-free peak;
    None: none). A pixel's noise is the power of ``looks`` independent complex Gaussian cells averaged (range bins
    or antennas collapsed into one Doppler row): gamma-distributed with shape ``looks`` and mean 1; ``looks`` = 1 is
    the exponential power of one cell. float64."""
    d0 = DEEP_FLOOR_DB
    power = 10.0 ** ((x.astype(np.float64) * d0 - d0) / 10.0)
    if noise_db is None:
        return power
    if int(looks) < 1:
        raise ValueError(f"noise looks must be a positive count, found {looks}")
    return power + 10.0 ** (noise_db / 10.0) * rng.gamma(float(int(looks)), 1.0 / int(looks), size=x.shape)


FINISHED = tuple(k for k, u in UNKNOWNS.items() if u.stage == "finish")  # what finish_rows applies
SCALING = {**{k: PROCESSING[k] for k in ("scale", "quantity", "normalise")}, "dynamic_range_db": None}  # defaults


def with_scaling(chain: ChainConfig, values: Mapping[str, float | str | None]) -> ChainConfig:
    """``chain`` with ``values``' scaling (:data:`SCALING`'s keys) over it; a default left unset, as in every cache."""
    return replace(chain, **{k: (None if values[k] == default else values[k])
                             for k, default in SCALING.items() if values.get(k) is not None})


def finish_rows(x: np.ndarray, values: Mapping[str, float | str | None], seed: int,
                processing: ChainConfig | None = None) -> np.ndarray:
    """Rows simulated at a ``DEEP_FLOOR_DB`` floor (dB, each row to its peak), approaching high, as the dataset shows
    them: receiver noise (``noise_db``, None: none; ``noise_looks`` cells averaged per pixel, default 1), then the
    dataset's processing (``processing``: its chain's quantity, scale, normalisation, CFAR and threshold; default
    the simulated rows' own) with ``values``' ``scale``, ``quantity``, ``normalise`` and ``dynamic_range_db`` over
    it, then the approaching end (``approaching``). What lay below the deep floor is lost: the CFAR's training cells
    and a column's own peak see at most ``DEEP_FLOOR_DB`` of range."""
    chain = with_scaling(processing or ChainConfig(dynamic_range_db=DEEP_FLOOR_DB), values)
    if chain.dynamic_range_db > DEEP_FLOOR_DB and (chain.scale or "db") == "db":
        raise ValueError(f"cannot show a {chain.dynamic_range_db:g} dB floor: the rows were simulated at "
                         f"{DEEP_FLOOR_DB:g} dB and what lay below it is lost")
    steps = (chain.quantity, chain.scale, chain.normalise, chain.cfar, chain.threshold)
    if values.get("noise_db") is not None or steps != (None,) * 5 or chain.dynamic_range_db != DEEP_FLOOR_DB:
        looks = values.get("noise_looks")
        power = noisy_power(x, values.get("noise_db"), np.random.default_rng([int(seed), 7]), 1 if looks is None else looks)
        x = power_to_unit(torch.from_numpy(power), chain).numpy().astype(np.float32)
    return mirror_doppler(x) if values.get("approaching", "high") == "low" else x


ONE_STEP: dict[str, dict] = {  # steps the unpaired gap report switches on alone over the fitted chain
    "linear power": {"scale": "linear", "quantity": None},
    "linear magnitude": {"scale": "linear", "quantity": "magnitude"},
    "per-frame scaling": {"normalise": "frame"},
    "CA-CFAR (guard 4, training 8, 10 dB)": {"cfar": (4, 8, 10.0)},
    "threshold 0.2": {"threshold": 0.2},
}


SIMULATED_STEPS: dict[str, dict] = {  # steps that need a simulation of their own: processing.<key> over the manifest's
    "no clutter removal": {"clutter_removal": "none"},
    "clutter removal per image": {"clutter_removal": "window"},
    "clutter removal per frame": {"clutter_removal": "frame"},
    "MTI canceller (lag 1)": {"clutter_removal": "mti", "mti_lag": 1},
    "strongest range bin": {"range": "strongest"},
    "sum over the range gate": {"range": "sum"},
}


def one_step_rows(x: np.ndarray, values: Mapping[str, float | str | None], seed: int,
                  chain: ChainConfig) -> dict[str, np.ndarray]:
    """Rows as simulated (``DEEP_FLOOR_DB``) finished by the fitted chain with each step of :data:`ONE_STEP` switched
    on alone (:func:`finish_rows`; a step the chain already takes is left out), by step name."""
    fitted = with_scaling(chain, values)
    rest = {k: v for k, v in values.items() if k not in SCALING}
    out = {}
    for name, step in ONE_STEP.items():
        changed = replace(fitted, **step)
        if changed != fitted:
            out[name] = finish_rows(x, rest, seed, changed)
    return out


def with_steps(m: Manifest, steps: Mapping) -> Manifest:
    """``m`` with ``steps`` (processing.<key>: value) over its stated processing."""
    return replace(m, processing={**m.processing, **steps}) if steps else m


def step_rows(real_path: str | Path, values: Mapping[str, float | str | None], *, per_class: int, seed: int,
              cache_dir: str | Path, sim: Mapping | None = None) -> dict[str, np.ndarray]:
    """The synthetic rows of :func:`synthesize_measured` (the same draws, in its order) with each step of
    :data:`ONE_STEP` (finished from the same simulation) or :data:`SIMULATED_STEPS` (simulated anew: a clutter filter,
    a range handling) switched on alone over the fitted chain, by step name; a step the chain already takes is left
    out. What the unpaired gap report compares with the measured rows."""
    m, shape = measured_manifest(real_path)
    made = dict(per_class=per_class, seed=seed, cache_dir=cache_dir, sim=sim)
    chain = dataset_chain(m, shape, values=values)
    simulated = load_arrays(synthesize_measured(real_path, values, **made, finish=False)).x
    out = one_step_rows(simulated, values, seed, chain)
    for name, step in SIMULATED_STEPS.items():
        if dataset_chain(with_steps(m, step), shape, values=values) != chain:
            log.info("the unpaired gap report's step %r: its own simulation (cached)", name)
            out[name] = load_arrays(synthesize_measured(real_path, values, **made, processing=step)).x
    return out


def synthesis_radar(m: Manifest, shape: tuple[int, int], values: Mapping[str, float]) -> RadarConfig:
    """A radar whose frame-based Doppler map has the dataset's grid: ``chirps_per_frame`` chirp loops a frame
    (default the Doppler FFT's bins, at most that: the chain zero-pads them to ``processing.doppler_fft``, else to
    the ``shape[0]`` rows), a loop period giving ``v_max_m_s`` (v_max = lambda / (4 T_loop)), ``frame_period_s`` a
    column.

    ``values`` gives the manifest's unknowns (fitted); the fast-time set-up (which only places the
    hand in range bins, summed over by the chain) is the AWR1843 default's. One TX, one RX."""
    known = {k: v for k, v in m.radar.items() if v != UNKNOWN}
    r = {**known, **{k: float(v) for k, v in values.items() if k in RADAR_FIELDS and v is not None}}
    missing = [k for k in ("carrier_hz", "v_max_m_s", "frame_period_s") if k not in r]
    if missing:
        raise ValueError(f"{m.path}: radar.{missing[0]} is unknown and not fitted")
    base = RadarConfig(start_freq_hz=r["carrier_hz"], idle_time_s=100e-6, adc_start_time_s=6e-6,
                       ramp_end_time_s=51.2e-6, slope_hz_per_s=76.22e12, n_samples=256, sample_rate_hz=10e6)
    loop_s = base.wavelength_m / (4.0 * r["v_max_m_s"])  # carrier_hz is the sweep start, as TI states it
    if loop_s <= base.ramp_end_time_s + 1e-6:
        raise ValueError(f"v_max {r['v_max_m_s']:g} m/s needs chirps of {loop_s * 1e6:.1f} us, shorter than the ramp")
    fft = int(m.processing["doppler_fft"] or shape[0])
    n_loops = int(r.get("chirps_per_frame", fft))
    if not 2 <= n_loops <= fft:
        raise ValueError(f"{m.path}: {n_loops} chirps a frame: expected 2 to the {fft} bins of its Doppler FFT")
    frame_s = float(r["frame_period_s"])
    if frame_s < n_loops * loop_s:
        raise ValueError(f"{n_loops} chirp loops of {loop_s * 1e3:.3f} ms (v_max {r['v_max_m_s']:g} m/s) do not fit in a "
                         f"{frame_s * 1e3:g} ms frame")
    return RadarConfig(start_freq_hz=base.start_freq_hz, idle_time_s=loop_s - base.ramp_end_time_s,
                       adc_start_time_s=base.adc_start_time_s, ramp_end_time_s=base.ramp_end_time_s,
                       slope_hz_per_s=base.slope_hz_per_s, n_samples=base.n_samples, sample_rate_hz=base.sample_rate_hz,
                       n_loops=n_loops, frame_period_s=frame_s, source=f"{m.name} (synthesis radar)")


def simulation_chain(chain: ChainConfig) -> ChainConfig:
    """The dataset's chain as the simulator runs it: its clutter filter, Doppler FFT and range handling, images in dB
    to each row's peak at ``DEEP_FLOOR_DB`` (what :func:`finish_rows` starts from)."""
    return replace(chain, dynamic_range_db=DEEP_FLOOR_DB, quantity=None, scale=None, normalise=None, reference_db=None,
                   cfar=None, threshold=None)


def motion_ranges(m: Manifest, values: Mapping[str, object] | None = None) -> tuple[dict, dict]:
    """The draw ranges of a manifest's motions, (shared, by class): its ``motion_ranges`` (the prior; the library's
    DEFAULT_RANGES where it states none) and each class's own, moved by ``values``' motion unknowns
    (handradar.data.unknowns.MOTION); a value that keeps its prior moves nothing, so a cache key stays as it was."""
    shared = {k: tuple(v) for k, v in m.motion_ranges.items()}
    by_class = {c: {k: tuple(v) for k, v in r.items()} for c, r in m.class_ranges.items()}
    for name in MOTION:
        u, value = UNKNOWNS[name], (values or {}).get(name)
        if value is None or u.keeps_prior(value):
            continue
        shared[u.motion] = u.moved(shared.get(u.motion, DEFAULT_RANGES[u.motion]), float(value))
        for r in by_class.values():
            if u.motion in r:
                r[u.motion] = u.moved(r[u.motion], float(value))
    return shared, by_class


def motion_source(m: Manifest, per_class: int, seed: int, duration_s: float,
                  values: Mapping[str, object] | None = None) -> dict:
    """The motion library's source config for a manifest's classes: the draw ranges of :func:`motion_ranges`."""
    shared, by_class = motion_ranges(m, values)
    return {"name": "motions", "classes": m.classes, "per_class": int(per_class), "seed": int(seed),
            "duration_s": float(duration_s), "ranges": {k: list(v) for k, v in shared.items()},
            "class_ranges": {c: {k: list(v) for k, v in r.items()} for c, r in by_class.items()}}


def synthesize_measured(real_path: str | Path, values: Mapping[str, float | str | None], *, per_class: int, seed: int,
                        cache_dir: str | Path, sim: Mapping | None = None, finish: bool = True,
                        processing: Mapping | None = None) -> Path:
    """Synthetic rows of a measured dataset's classes, cached by everything that makes them. ``values`` holds the
    manifest's unknowns (handradar.data.unknowns): the radar ones set the radar (:func:`synthesis_radar`) and its
    range handling, the motion ones the motions' draw ranges (:func:`motion_ranges`), the others finish the rows
    simulated at a deep floor (:func:`finish_rows`) with the dataset's processing; ``finish`` False: the rows as
    simulated (what the fit finishes candidate by candidate). ``processing``: steps over the manifest's (its
    ``processing.<key>``), as :func:`step_rows` switches them on."""
    m, shape = measured_manifest(real_path)
    m = with_steps(m, processing or {})
    radar = synthesis_radar(m, shape, values)
    chain = dataset_chain(m, shape, radar.n_loops, values)
    source = motion_source(m, per_class, seed, shape[1] * radar.frame_period_s, values)
    spans = [source["ranges"].get("distance_m", DEFAULT_RANGES["distance_m"]),
             *(r["distance_m"] for r in source["class_ranges"].values() if "distance_m" in r)]
    near, far = min(lo for lo, _ in spans), max(hi for _, hi in spans)
    if near < chain.gate_m[0] or far > chain.gate_m[1]:  # a hand outside the gate would be cut without a word
        raise FormatError(m.path, f"manifest {m.name!r} draws the hands {near:g}-{far:g} m from the radar "
                                  f"(motion_ranges.distance_m, moved by the fit where it moves them), outside "
                                  f"processing.range_gate_m "
                                  f"[{chain.gate_m[0]:g}, {chain.gate_m[1]:g}]: widen the gate or narrow the range")
    simulated = simulation_chain(chain)
    # measured/2: rendered by Simulator.render_rows (no float16 slot-profile cache in between)
    key = config_hash(source, radar, simulated, dict(sim or {}), 'measured/2', library_key())
    out = Path(cache_dir) / f"measured-synth-{key}.h5"
    if not out.is_file():
        log.info("synthesising %d rows per class of %d classes (v_max %.2f m/s, %.1f ms per column, %d chirps a frame)",
                 per_class, len(m.classes), radar.max_velocity_m_s, radar.frame_period_s * 1e3, radar.n_loops)
        synthesize_source(source, out, radar=radar, chain=simulated, sim=dict(sim or {}) or None,
                          cache_dir=Path(cache_dir) / "profiles", progress=False)
    steps = {k: values.get(k) for k in FINISHED}
    if steps["noise_db"] is None:
        steps["noise_looks"] = None  # no noise: its looks change nothing
    if not finish or (chain == simulated and all(steps[k] in (None, "high") for k in ("noise_db", "approaching"))):
        return out
    finished = out.with_name(f"{out.stem}-{config_hash(steps, chain, seed)}.h5")
    if not finished.is_file():
        with atomic_path(finished) as tmp:
            shutil.copyfile(out, tmp)
            with h5py.File(tmp, "r+") as h5:
                h5["spectrograms"][...] = finish_rows(h5["spectrograms"][()], steps, seed, chain)
                h5.attrs["finish"] = json.dumps(steps)
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
    edges: list[str] = field(default_factory=list)  # unknowns chosen at the edge of their grid (grid_edges)
    kept: dict[str, dict] = field(default_factory=dict)  # motion unknown -> {best, wins}: its prior kept (PRIOR_KEPT_BELOW)
    passes: int = 1                 # rounds of the motions' search (each after the radar and processing were refitted)

    @classmethod
    def from_dict(cls, d: Mapping) -> UnknownsFit:
        """The fit :meth:`as_dict` wrote (the cached ``measured-fit-<hash>.json``)."""
        return cls(**{k: d[k] for k in ("values", "candidates", "shares", "ranges", "n_rows", "n_boot")},
                   objective=next(k for k, v in OBJECTIVES.items() if v == d.get("objective", OBJECTIVES["means"])),
                   edges=list(d.get("edges", [])), kept=dict(d.get("kept", {})), passes=int(d.get("passes", 1)))

    def as_dict(self) -> dict:
        return {"values": self.values, "candidates": self.candidates, "shares": self.shares, "ranges": self.ranges,
                "n_rows": self.n_rows, "objective": OBJECTIVES[self.objective], "n_boot": self.n_boot,
                "edges": self.edges, "kept": self.kept, "passes": self.passes}

    def summary(self) -> str:
        parts = []
        for k, v in self.values.items():
            edge = " AT THE EDGE of its grid" if k in self.edges else ""
            if not self.n_boot:
                parts.append(f"{k} {v}{edge}")
                continue
            if k not in self.shares:  # fixed: nothing was chosen
                parts.append(f"{k} {v}")
                continue
            share = self.shares[k].get(str(v), 0.0)
            rng = f" [{self.ranges[k][0]:g}, {self.ranges[k][1]:g}]" if k in self.ranges else ""
            kept = (f", the prior kept: {self.kept[k]['best']:g} beat it in only {self.kept[k]['wins']:.0%}"
                    if k in self.kept else "")
            parts.append(f"{k} {v}{rng}{edge} (chosen by {share:.0%} of resamples{kept})")
        text = "; ".join(parts)
        if self.passes > 1:
            text += f" ({self.passes} passes: the radar and processing refitted at the fitted motions)"
        if not self.n_boot:
            text += " (uncertainty not estimated: a class has fewer than 2 rows to resample)"
        if self.edges:
            text += (f". Widen the grid beyond the edge: synth.measured.fit.grid.{self.edges[0]}=[...] "
                     "(docs/datasets.md#fitting-what-the-manifest-leaves-unknown)")
        if self.values.get("dynamic_range_db") == DEEP_FLOOR_DB:
            text += (f"; the dB floor lies at the deepest the simulated rows keep ({DEEP_FLOOR_DB:g} dB): a deeper one "
                     "needs DEEP_FLOOR_DB raised (handradar.synthesis.measured)")
        return text


def fit_unknowns(real_x: np.ndarray, real_y: np.ndarray, n_classes: int,
                 simulate: Callable[[dict], tuple[np.ndarray, np.ndarray] | None],
                 grid: Mapping[str, Sequence], *, n_boot: int = 200, boot_candidates: int = 16,
                 seed: int = 0, objective: str = "means", processing: ChainConfig | None = None,
                 passes: int = 2) -> UnknownsFit:
    """Choose the unknowns whose synthetic class means (and spreads) are closest to the measured ones (module docstring).

    simulate({radar and motion unknowns}) -> (x, y): synthetic rows as simulated (``DEEP_FLOOR_DB``, approaching high),
    None where that radar is no candidate (a frame too short for its chirps). grid: candidates by unknown
    (handradar.data.unknowns.UNKNOWNS; a single-value list fixes one, an absent one is not fitted: None is passed
    to ``simulate``, or ``processing`` keeps its step); ``chirps_per_frame``, ``noise_db`` and ``noise_looks`` default
    to [None] (as many chirps as Doppler bins), [None] (no noise) and [1]. The rows of each candidate are finished
    (:func:`finish_rows`) on ``processing``. The radar and finish unknowns are searched over every combination, the
    motions' draws at their prior (a motion unknown's identity, or its one candidate); then each motion unknown in
    turn (grid order) over its candidates, at the chosen radar, finish and earlier motions. Where a motion moved,
    the radar and finish combinations are searched again at the fitted motions (the speed trades against v_max and
    the time a column, and the first choice was made at the prior's speed) and, where that changed them, the motions
    again: at most ``passes`` rounds of the motions' search. The bootstrap re-ranks the ``boot_candidates`` best
    combinations, and each motion unknown's candidates; it is skipped (``n_boot`` 0 in the result: no uncertainty)
    where a class has fewer than 2 rows, whose every resample is the same rows; each resample redraws the
    candidates' synthetic rows too (the same rows for every candidate). A motion unknown leaves its prior only for a
    candidate that beats it in ``PRIOR_KEPT_BELOW`` of the resamples (``kept`` in the result names those held back):
    a move the rows cannot tell from the synthetic rows' own sampling is not made
    (docs/datasets.md#fitting-the-motions). ``objective``: :data:`OBJECTIVES`.
    """
    optional = {"chirps_per_frame": [None], "noise_db": [None], "noise_looks": [1]}
    if passes < 1:
        raise ValueError(f"the fit needs at least one pass, found passes={passes}")
    unknown = sorted(set(grid) - set(UNKNOWNS))
    if unknown:
        raise ValueError(f"unknown fit grid entry {unknown[0]!r}; expected one of {list(UNKNOWNS)}")
    g = {k: list(grid.get(k) or optional[k]) for k in UNKNOWNS if grid.get(k) or k in optional}
    radar_keys = [k for k in g if UNKNOWNS[k].stage == "radar"]
    finished = [k for k in g if UNKNOWNS[k].stage == "finish"]
    motions = {k: float(g[k][0]) if len(g[k]) == 1 else UNKNOWNS[k].identity
               for k in g if UNKNOWNS[k].stage == "motion"}

    def objectives(real_moments: np.ndarray, synth: np.ndarray) -> np.ndarray:
        """The objective of each candidate's moments ``synth`` (candidates, images, doppler, columns)."""
        flat = np.broadcast_to(real_moments, synth.shape).reshape(-1, *real_moments.shape[-2:]).copy()
        s = per_example_ssim(flat, synth.reshape(-1, *real_moments.shape[-2:])).reshape(len(synth), -1)
        return 1.0 - s.mean(axis=1)

    members = [np.flatnonzero(real_y == c) for c in range(n_classes)]
    if min(len(m) for m in members) < 2:
        n_boot = 0
    rng = np.random.default_rng(seed)
    resamples = [class_moments(real_x[rows], real_y[rows], n_classes, objective) for rows in
                 (np.concatenate([rng.choice(m, size=len(m)) for m in members]) for _ in range(n_boot))]
    real_moments = class_moments(real_x, real_y, n_classes, objective)

    synth_rng = np.random.default_rng([seed, 1])  # the synthetic rows' resamples: the measured ones' stay as they were

    def redraws(y: np.ndarray) -> list[np.ndarray]:
        """One redraw of synthetic rows labelled ``y`` per resample, each class within itself: the same rows for every
        candidate, whose motion draws are shared, so that their own sampling moves a close ranking."""
        members = [np.flatnonzero(y == c) for c in range(n_classes)]
        return [np.concatenate([synth_rng.choice(m, size=len(m)) for m in members]) for _ in resamples]

    def radar_stage(motion_values: dict) -> tuple[dict, dict, list[dict]]:
        """Every combination of the radar and finish unknowns at ``motion_values``: the best, each resample's
        choices by unknown, and every candidate with its objective."""
        combos, synth_moments, made_from = [], [], []  # made_from: each combo's simulated rows and finish values
        for radar_values in itertools.product(*(g[k] for k in radar_keys)):
            radar = {k: (v if v is None or not UNKNOWNS[k].numeric else int(v) if UNKNOWNS[k].kind == "count"
                         else float(v)) for k, v in zip(radar_keys, radar_values)}
            made = simulate({**radar, **motion_values})
            if made is None:
                continue
            x, y = made
            for rest in itertools.product(*(g[k] for k in finished)):
                values = {**radar, **dict(zip(finished, rest))}
                if values.get("noise_db") is None and values.get("noise_looks", 1) != g.get("noise_looks", [1])[0]:
                    continue  # without noise its looks change nothing: one candidate
                if (values.get("scale", "db") == "db"
                        and values.get("quantity") not in (None, g.get("quantity", [None])[0])):
                    continue  # in dB a magnitude's image is its power's: one candidate
                values = {k: (int(v) if k == "noise_looks" else float(v) if isinstance(v, (int, float)) else v)
                          for k, v in values.items()}
                combos.append({**values, **motion_values})
                made_from.append((x, np.asarray(y), values))
                synth_moments.append(class_moments(finish_rows(x, values, seed, processing), y, n_classes, objective))
        if not combos:
            raise ValueError("no candidate of the grid could be simulated")
        synth_moments = np.stack(synth_moments)  # (combos, classes or 2 classes, doppler, columns)
        gaps = objectives(real_moments, synth_moments)
        # the resamples re-rank the best candidates only: SSIM costs ~9 ms a pair on one core, and a candidate far
        # behind on all rows is not chosen by a resample of them; each redraws the measured and the synthetic rows
        contenders = np.argsort(gaps, kind="stable")[:boot_candidates]
        rows = [(finish_rows(x, values, seed, processing), y) for x, y, values in (made_from[i] for i in contenders)]
        y = rows[0][1]
        if any(not np.array_equal(y, other) for _, other in rows):
            raise ValueError("the candidates' synthetic rows differ in their labels: simulate must draw the same rows")
        picks = redraws(y)
        winners = [combos[contenders[np.argmin(objectives(r, np.stack([class_moments(x[pick], y[pick], n_classes,
                                                                                      objective) for x, _ in rows])))]]
                   for r, pick in zip(resamples, picks)]
        return (dict(combos[int(np.argmin(gaps))]), {k: [w[k] for w in winners] for k in g if k not in motions},
                [{**c, "gap": float(gap)} for c, gap in zip(combos, gaps)])

    def motion_stage(values: dict) -> tuple[dict, dict, dict, list[dict]]:
        """Each motion unknown in turn over its candidates at ``values``: the values after it, each resample's
        choices, the priors kept (:data:`PRIOR_KEPT_BELOW`) and every candidate with its objective."""
        values, chosen, kept, candidates = dict(values), {}, {}, []
        for name in (k for k in motions if len(g[k]) > 1):
            identity = UNKNOWNS[name].identity
            tried, made_rows = [], []
            # ties: the candidate nearest the prior
            for v in sorted(map(float, g[name]), key=lambda v: abs(v - identity)):
                made = simulate({**{k: values[k] for k in radar_keys}, **{k: values[k] for k in motions}, name: v})
                if made is None:
                    continue
                x = finish_rows(made[0], values, seed, processing)
                # a shift clipped at 0 makes the same draws: one candidate
                if not any(np.array_equal(x, earlier) for earlier, _ in made_rows):
                    tried.append(v)
                    made_rows.append((x, np.asarray(made[1])))
            if not tried:
                raise ValueError(f"no candidate of {name} could be simulated")
            gaps = objectives(real_moments, np.stack([class_moments(x, y, n_classes, objective) for x, y in made_rows]))
            best = int(np.argmin(gaps))
            candidates += [{**values, name: v, "gap": float(gap)} for v, gap in zip(tried, gaps)]
            y = made_rows[0][1]
            boot = np.zeros((len(resamples), len(tried)))
            for i, (real_r, pick) in enumerate(zip(resamples, redraws(y))):
                boot[i] = objectives(real_r, np.stack([class_moments(x[pick], y[pick], n_classes, objective)
                                                       for x, _ in made_rows]))
            chosen[name] = [tried[i] for i in boot.argmin(axis=1)]
            wins = float(np.mean(boot[:, best] < boot[:, 0])) if resamples else 1.0
            if best and tried[0] == identity and wins < PRIOR_KEPT_BELOW:
                kept[name] = {"best": tried[best], "wins": wins}
                best = 0
            values[name] = tried[best]
        return values, chosen, kept, candidates

    values, chosen, candidates = radar_stage(motions)
    kept: dict[str, dict] = {}
    for n_pass in range(1, passes + 1):
        moved, chosen_motions, kept, tried = motion_stage(values)
        chosen.update(chosen_motions)
        candidates += tried
        if n_pass == passes or all(moved[k] == values[k] for k in motions):
            values = moved
            break
        # the motions moved: the radar and processing again at them (the speed trades against v_max and a column)
        again, chosen_radar, tried = radar_stage({k: moved[k] for k in motions})
        chosen.update(chosen_radar)
        candidates += tried
        if all(again[k] == values[k] for k in g if k not in motions):
            values = moved
            break
        values = again
    shares = {k: {str(v): c.count(v) / n_boot for v in dict.fromkeys(c)} for k, c in chosen.items()} if n_boot else {}
    ranges = {k: [float(np.percentile(c, q)) for q in (2.5, 97.5)] for k, c in chosen.items()
              if n_boot and UNKNOWNS[k].numeric and all(v is not None for v in c)}
    return UnknownsFit(values=values, candidates=candidates, shares=shares, ranges=ranges,
                       n_rows=int(len(real_y)), objective=objective, n_boot=int(n_boot), edges=grid_edges(values, g),
                       kept=kept, passes=n_pass)


def grid_edges(values: Mapping[str, object], grid: Mapping[str, Sequence]) -> list[str]:
    """The numeric unknowns whose chosen value is the smallest or largest of three or more candidates: the best may
    lie beyond the grid."""
    out = []
    for k, v in values.items():
        numbers = sorted(c for c in grid.get(k, []) if c is not None)
        if UNKNOWNS[k].numeric and v is not None and len(numbers) >= 3 and v in (numbers[0], numbers[-1]):
            out.append(k)
    return out
