"""Synthetic spectrograms from skeletons: the providers of train.py and ``handradar-synth``.

Two paths, one simulator:

- rows of a radar dataset (:func:`synthesize_rows`, the ``synth.provider`` of train.py): each
  requested row's skeleton window is simulated with the modelling-only simulator (mode "model")
  or with simulator + RadarWeightNet fitted on the radar data of ``fit_rows`` (mode "enhanced": with
  ``guard_folds`` >= 2 fitted with held-out rows and shrunk toward weight 1 where they show no gain,
  handradar.synthesis.fit.guarded_weight_net; its report in the file's attribute ``rwn_guard``);
- sequences of any skeleton source (:func:`synthesize_source`, used by ``handradar-synth`` and the
  ``synth.external_provider``): each sequence is resampled to the simulator's skeleton rate, the
  spectrogram-long window with the most joint motion is simulated (the gesture), optionally
  weighted by a RadarWeightNet checkpoint.

Outputs are ``handradar.dataset/1`` files, cached under ``cache_dir`` by a hash of everything that
determines them and written atomically. RadarWeightNet checkpoints (:func:`save_weight_net`) hold
the network's settings and weights and the hand model and skeleton rate they were trained with.

The provider contracts (train.py's ``synth.provider`` and ``synth.external_provider``):
Synthetic spectrograms enter train.py jobs through two Hydra-instantiated callables
(``synth.provider`` and ``synth.external_provider``, both ``_partial_: true``):

``provider(real_path: Path, rows: np.ndarray, mode: Literal["model", "enhanced"], *, fit_rows: np.ndarray,
seed: int, cache_dir: Path[, sim: Mapping]) -> Path``
    One synthetic spectrogram per requested row of the real dataset ``real_path``, simulated from
    that row's skeleton, written as a ``handradar.dataset/1`` file whose rows follow ``rows`` (same
    labels and meta order). ``mode="model"``: the modelling-only simulator; ``mode="enhanced"``:
    simulator + RadarWeightNet, which the provider may fit on the radar data of ``fit_rows`` only
    (the few-shot real rows; never the test rows). ``cache_dir`` is the provider's to cache in.
    ``sim`` (passed only when train.py fits the simulator or draws nuisance parameters,
    ``synth.fit_sim`` / ``synth.randomize``): the ``sim`` settings to simulate with instead of the
    provider's own.

``external_provider(source_cfg, *, seed: int, cache_dir: Path) -> Path``
    Spectrograms synthesised from an external skeleton dataset (``source_cfg`` is the
    ``data.sfinge3d`` or ``data.dhg`` node: ``name``, ``root``, ...), as a ``handradar.dataset/1``
    file with the source's own labels and the class names in the attribute ``classes``.

The defaults are :func:`synthesize_rows` and :func:`synthesize_external` (conf/train.yaml);
:func:`load_synthetic` checks what a provider returned.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any, Literal

import h5py
import numpy as np
from omegaconf import DictConfig, OmegaConf

from handradar.data.datasets import ArrayDataset, file_hash, load_arrays
from handradar.data.hdf5 import open_writer, read_attrs, read_meta_group, read_rows
from handradar.data.skeletons import iter_source, source_classes
from handradar.errors import FormatError
from handradar.hand.model import HandModelConfig
from handradar.hand.motions import library_key
from handradar.hand.skeleton import HandSequence
from handradar.provenance import config_hash
from handradar.radar.chain import ChainConfig
from handradar.radar.config import RadarConfig
from handradar.sim.cache import DatasetCaches, SlotProfileCache, cache_slot_profiles
from handradar.sim.factory import SimFactory
from handradar.sim.features import cached_bone_features
from handradar.sim.simulator import Simulator
from handradar.synthesis.fit import (
    GUARD_RULE,
    Phase,
    fit_weight_net,
    guarded_weight_net,
    load_pairs,
    load_weight_net,
    predict_cached,
    schedule,
)


SimSpec = DictConfig | Mapping | Simulator | None  # the ``sim`` config, a built simulator, or None (the paper's)


def simulator_for(sim: SimSpec, radar: RadarConfig, chain: ChainConfig,
                  skeleton_rate_hz: float | None = None) -> Simulator:
    """The simulator of ``radar``/``chain``: built by :class:`SimFactory` from the ``sim`` config
    (None: the paper's model), or ``sim`` itself when it is a simulator of that radar and chain."""
    if isinstance(sim, Simulator):
        if sim.radar != radar or sim.chain != chain:
            raise ValueError("the simulator's radar/chain differ from the data's")
        return sim
    rate = {} if skeleton_rate_hz is None else {"skeleton_rate_hz": float(skeleton_rate_hz)}
    return SimFactory.from_config(sim, radar, chain, **rate)()


# ---- caches of dataset rows --------------------------------------------------------------------------
def dataset_simulator(dataset: str | Path, sim: SimSpec) -> Simulator:
    """The simulator of a dataset file's radar, chain and skeleton rate."""
    attrs = read_attrs(dataset)
    if attrs.get("radar") is None or attrs.get("chain") is None:
        raise FormatError(dataset, "needs the attributes radar_cfg and chain to simulate its rows")
    return simulator_for(sim, attrs["radar"], attrs["chain"], attrs.get("skeleton_rate_hz"))


def cache_rows(dataset: str | Path, rows: np.ndarray, sim: Simulator, cache_dir: str | Path, *,
               features: bool = True, n_jobs: int = 2, progress: bool = False) -> DatasetCaches:
    """Features and slot profiles of ``rows`` of a dataset (cached; indexed 0..len(rows)-1).

    Only the requested rows are simulated: a few-shot job needs a few dozen, not the whole file.
    Without ``features`` (modelling only, no occlusion effect) no visibility is ray cast.
    """
    rows = np.asarray(rows, dtype=np.int64)
    uniq, inv = np.unique(rows, return_inverse=True)
    with h5py.File(dataset, "r") as h5:
        skel = read_rows(h5["skeletons"], uniq)[inv]
        mask = read_rows(h5["hand_mask"], uniq)[inv]
    times = np.arange(skel.shape[1]) / sim.skeleton_rate_hz
    needs_vis = any(e.name == "occlusion" for e in sim.effects)
    feats = None
    if features or needs_vis:
        feats = cached_bone_features(skel, times, mask, sim.radar.wavelength_m, sim.hand, cache_dir,
                                     rcs_exponent=sim.rcs_exponent, progress=progress, n_jobs=n_jobs)
    # times=None: the simulator's default step times, so the key matches cache_dataset's
    path = cache_slot_profiles(sim, skel, mask, cache_dir, visibility=feats.visible_fraction() if needs_vis else None,
                               progress=progress)
    return DatasetCaches(feats, mask, times, SlotProfileCache(path))


def spectrograms_of(dataset: str | Path, rows: np.ndarray) -> np.ndarray:
    """Measured spectrograms of ``rows`` (any order), (N, doppler, columns)."""
    uniq, inv = np.unique(np.asarray(rows, dtype=np.int64), return_inverse=True)
    with h5py.File(dataset, "r") as h5:
        return read_rows(h5["spectrograms"], uniq)[inv]


# ---- writing synthetic datasets ------------------------------------------------------------------------
def _write_rows_like(out: Path, real_path: Path, rows: np.ndarray, spectrograms: np.ndarray, h: str,
                     sim: Simulator, mode: str, extra_attrs: Mapping[str, str] | None = None) -> Path:
    """A dataset with the labels, skeletons and meta of ``rows`` of ``real_path`` and new spectrograms."""
    attrs = read_attrs(real_path)
    meta = read_meta_group(real_path)
    with h5py.File(real_path, "r") as h5:
        labels, skel, mask = h5["labels"][()], h5["skeletons"], h5["hand_mask"]
        with open_writer(out, classes=attrs["classes"], radar=attrs["radar"], chain=attrs["chain"],
                         skeleton_rate_hz=float(attrs["skeleton_rate_hz"]), n_steps=skel.shape[1], config_hash=h,
                         extra_attrs={"source": f"handradar.synth:{mode}", "synthetic_of": str(real_path),
                                      **(extra_attrs or {})}) as w:
            for i, r in enumerate(rows):
                r = int(r)
                w.append(spectrograms[i], int(labels[r]), skel[r], mask[r], float(h5["window_start_s"][r]),
                         {k: (v[r].item() if hasattr(v[r], "item") else v[r]) for k, v in meta.items()})
    return out


def synthesize_rows(real_path: str | Path, rows: np.ndarray, mode: Literal["model", "enhanced"], *,
                    fit_rows: np.ndarray, seed: int, cache_dir: str | Path, sim: SimSpec = None,
                    phases: Sequence[Phase | dict] | None = None, net_kwargs: dict | None = None,
                    guard_folds: int = 0, n_jobs: int = 2) -> Path:
    """``synth.provider`` (contract in handradar.synthesis.providers): one synthetic row per requested row.

    mode "enhanced" fits RadarWeightNet on the radar data of ``fit_rows`` only (never test rows);
    ``guard_folds`` >= 2: with that many held-out folds of them, shrunk toward weight 1 where they show
    no gain (handradar.synthesis.fit.guarded_weight_net); 0: the paper's one fit.
    """
    real_path = Path(real_path)
    rows = np.asarray(rows, dtype=np.int64)
    fit_rows = np.asarray(fit_rows, dtype=np.int64)
    if mode not in ("model", "enhanced"):
        raise ValueError(f"mode must be 'model' or 'enhanced', found {mode!r}")
    simulator = dataset_simulator(real_path, sim)
    phases = schedule(phases)

    key = config_hash(file_hash(real_path), rows.tolist(), mode, fit_rows.tolist() if mode == "enhanced" else None,
                      seed, simulator.key(), [asdict(p) for p in phases] if mode == "enhanced" else None,
                      net_kwargs or {}, *([guard_folds, GUARD_RULE] if mode == "enhanced" and guard_folds else []))
    out = Path(cache_dir) / f"synthetic-{mode}-{key}.h5"
    if out.is_file():
        return out
    cache_dir = Path(cache_dir)
    extra: dict[str, str] = {}
    if mode == "model":
        caches = cache_rows(real_path, rows, simulator, cache_dir, features=False, n_jobs=n_jobs)
        spec = predict_cached(simulator, None, caches, np.arange(len(rows))).numpy()
    else:
        both = np.union1d(rows, fit_rows)
        caches = cache_rows(real_path, both, simulator, cache_dir, features=True, n_jobs=n_jobs)
        targets = spectrograms_of(real_path, both)
        local = {int(r): i for i, r in enumerate(both)}
        train = load_pairs(caches, targets, np.asarray([local[int(r)] for r in fit_rows]))
        if guard_folds >= 2:
            with h5py.File(real_path, "r") as h5:
                labels = h5["labels"][()][fit_rows]
            net, report = guarded_weight_net(simulator, train, labels, folds=guard_folds, phases=phases, seed=seed,
                                             net_kwargs=net_kwargs)
            extra = {"rwn_guard": json.dumps(report)}  # train.py logs it (Job.log_rwn_guard)
        else:
            net = fit_weight_net(simulator, train, phases=phases, seed=seed, net_kwargs=net_kwargs)
        del train
        spec = predict_cached(simulator, net, caches, np.asarray([local[int(r)] for r in rows])).numpy()
    return _write_rows_like(out, real_path, rows, spec.astype(np.float32), key, simulator, mode, extra)


# ---- skeleton sources ----------------------------------------------------------------------------------
def motion_window(seq: HandSequence, n_steps: int, rate_hz: float) -> HandSequence:
    """The ``n_steps``-long window (at ``rate_hz``) of the sequence with the most joint motion.

    Sequences shorter than the window are centred in it, holding their first and last pose (a still
    hand adds nothing after clutter removal). Times of the result run from 0.
    """
    dt = 1.0 / rate_hz
    t0, t1 = float(seq.times[0]), float(seq.times[-1])
    n_own = int(np.floor((t1 - t0) / dt)) + 1
    if n_own <= n_steps:
        start = t0 - 0.5 * (n_steps - n_own) * dt
    else:
        grid = seq.resample(t0 + np.arange(n_own) * dt)
        speed = np.zeros(n_own)
        moving = np.linalg.norm(np.diff(grid.positions, axis=0), axis=-1).sum(axis=(-2, -1))
        speed[1:] = moving
        sums = np.convolve(speed, np.ones(n_steps), mode="valid")
        start = t0 + int(np.argmax(sums)) * dt
    window = seq.resample(start + np.arange(n_steps) * dt)
    window.times = np.arange(n_steps) * dt
    return window


def source_options(source_cfg: Any) -> tuple[str, str, dict]:
    """(name, root, options) of a ``source`` config node (name, root, and the source's options)."""
    d = OmegaConf.to_container(source_cfg, resolve=True) if isinstance(source_cfg, DictConfig) else dict(source_cfg)
    name, root = d.pop("name", None), d.pop("root", None)
    if not name or (not root and name != "motions"):  # the motion library reads no folder
        raise ValueError(f"a skeleton source needs 'name' and 'root', found {sorted(d) + ['name', 'root']}")
    return str(name), str(root or ""), {k: v for k, v in d.items() if v is not None}


def synthesize_source(source_cfg: Any, out: str | Path, *, radar: RadarConfig, chain: ChainConfig, sim: SimSpec = None,
                      weights: str | Path | None = None, skeleton_rate_hz: float = 100.0, n_jobs: int = 2,
                      cache_dir: str | Path | None = None, progress: bool = True,
                      skipped: list | None = None) -> Path:
    """Skeletons of any source -> synthetic spectrograms in the dataset schema at ``out``.

    Labels are the source's own class indices (class names in the attribute ``classes``).
    weights: a RadarWeightNet checkpoint (:func:`save_weight_net`); None: modelling only.
    skipped: a list receiving (item, reason) for unreadable items (default: raise).
    """

    name, root, options = source_options(source_cfg)
    net, info = (None, {}) if weights is None else load_weight_net(weights)
    if info:
        skeleton_rate_hz = float(info["skeleton_rate_hz"])
        sim_hand = HandModelConfig(**info["hand"])
    simulator = simulator_for(sim, radar, chain, skeleton_rate_hz)
    if info and simulator.hand != sim_hand:
        raise FormatError(weights, f"checkpoint trained with hand model {sim_hand}, simulator uses {simulator.hand}")
    n_steps = int(round(chain.frames_per_window(radar) * radar.frame_period_s * skeleton_rate_hz))
    items = list(iter_source(name, root, errors=skipped, **options))
    if not items:
        raise FormatError(root, f"no {name} sequences found")
    windows = [motion_window(it.sequence, n_steps, skeleton_rate_hz) for it in items]
    skel = np.stack([w.positions for w in windows])
    mask = np.stack([w.mask for w in windows])
    arms = np.stack([w.arm for w in windows]) if all(w.arm is not None for w in windows) else None
    times = windows[0].times
    occlusion = any(e.name == "occlusion" for e in simulator.effects)
    if net is None and not occlusion:  # modelling only: the slots are summed as simulated, never stored
        spec = simulator.render_rows(skel, mask, times=times, arms=arms, progress=progress).numpy().astype(np.float32)
    else:
        cache_dir = Path(cache_dir) if cache_dir is not None else Path(out).parent / ".handradar-cache"
        feats = cached_bone_features(skel, times, mask, radar.wavelength_m, simulator.hand, cache_dir,
                                     rcs_exponent=simulator.rcs_exponent, progress=progress, n_jobs=n_jobs)
        path = cache_slot_profiles(simulator, skel, mask, cache_dir, times=times, arms=arms, progress=progress,
                                   visibility=feats.visible_fraction() if occlusion else None)
        caches = DatasetCaches(feats, mask, times, SlotProfileCache(path))
        spec = predict_cached(simulator, net, caches, np.arange(len(items))).numpy().astype(np.float32)
    classes = source_classes(name, **{k: v for k, v in options.items() if k in ("n_classes", "classes")})
    h = config_hash(name, root, options, simulator.key(), str(weights), "handradar-synth")
    meta_keys = sorted(set().union(*(it.meta.keys() for it in items)))
    with open_writer(out, classes=classes, radar=radar, chain=chain, skeleton_rate_hz=skeleton_rate_hz,
                     n_steps=n_steps, config_hash=h,
                     extra_attrs={"source": f"handradar.synth:{name}", "weights": str(weights or "")}) as w:
        for i, (it, win) in enumerate(zip(items, windows)):
            meta = {k: it.meta.get(k, "") for k in meta_keys}
            meta["recording"] = it.name
            w.append(spec[i], it.label, win.positions, win.mask, 0.0, meta)
    return Path(out)


def synthesize_external(source_cfg: Any, *, seed: int, cache_dir: str | Path, radar: RadarConfig,
                        chain: ChainConfig, sim: SimSpec = None, weights: str | Path | None = None) -> Path:
    """``synth.external_provider`` (contract in handradar.synthesis.providers): a cached handradar-synth run."""
    name, root, options = source_options(source_cfg)
    simulator = simulator_for(sim, radar, chain)
    # external/2: without weights rendered by Simulator.render_rows (no float16 slot-profile cache in between)
    library = [library_key()] if name == "motions" else []  # the motion library's kinematics make its rows
    key = config_hash(name, str(Path(root).resolve()), options, simulator.key(), str(weights), "external/2", *library)
    out = Path(cache_dir) / f"external-{name}-{key}.h5"
    if not out.is_file():
        synthesize_source(source_cfg, out, radar=radar, chain=chain, sim=simulator, weights=weights,
                          cache_dir=cache_dir, progress=False)
    return out


def load_synthetic(path: str | Path, expected_labels: np.ndarray, shape: tuple[int, int] = (64, 32)) -> ArrayDataset:
    """A provider's output, checked against the rows it was asked for (count, labels in order, shape)."""
    data = load_arrays(path)
    expected_labels = np.asarray(expected_labels)
    if len(data) != len(expected_labels):
        raise FormatError(path, f"synthetic dataset has {len(data)} rows, the provider was asked for {len(expected_labels)}")
    if not np.array_equal(data.y, expected_labels):
        bad = int(np.flatnonzero(data.y != expected_labels)[0])
        raise FormatError(path, f"synthetic row {bad} has label {data.y[bad]}, the requested row's label is "
                                f"{expected_labels[bad]} (rows must follow the requested order)")
    if data.x.shape[1:] != tuple(shape) or not np.isfinite(data.x).all() or data.x.min(initial=0) < 0 or data.x.max(initial=0) > 1:
        raise FormatError(path, f"synthetic spectrograms must be (N, {shape[0]}, {shape[1]}) in [0, 1], found {data.x.shape} "
                                f"in [{data.x.min(initial=0):.3g}, {data.x.max(initial=0):.3g}]")
    return data
