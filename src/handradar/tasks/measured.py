"""The measured-radar job (``python train.py +experiment=measured data.manifest=FILE split.per_class=K``).

A measured spectrogram dataset (handradar.data.measured: no skeletons) is split by its manifest:
training rows come from its ``train`` split, of which ``split.val_per_class`` rows per class
(fixed, ``split.test_seed``) are the validation rows every setting is chosen on; ``split.per_class``
rows per class (nested across K for one seed; ``all``: every other training row; 0: none) train the
classifiers. Each ``test`` split (held-out users) is only reported.

Synthetic rows come from the motion library (handradar.hand.motions) through the classes' motions,
simulated with the radar and chain that reproduce the dataset's processing
(:func:`handradar.data.measured.synthesis_radar`, frame-based Doppler) at the manifest's known values
and ``synth.measured`` for its unknowns. Variants (``MEASURED_VARIANTS``):

- ``radar_only``: the K real rows;
- ``model_synth``: the K real rows + the synthetic rows;
- ``model_synth_only``: the synthetic rows alone (K = 0 is this variant alone);
- ``synth_pretrain``: trained on the synthetic rows, then fine-tuned on the K real rows.

Metrics: ``val/acc_<variant>`` and ``test/acc_<variant>_<split>`` for each test split.
"""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path
from typing import TYPE_CHECKING

import h5py
import numpy as np
from omegaconf import OmegaConf

from handradar.atomic import atomic_path
from handradar.data.datamodule import FileRows
from handradar.data.datasets import load_arrays
from handradar.data.hdf5 import read_attrs
from handradar.data.measured import UNKNOWN, Manifest, dataset_chain, synthesis_radar
from handradar.data.splits import _class_permutation
from handradar.errors import FormatError, TooFewRows
from handradar.models.classifiers import backbone_state
from handradar.provenance import config_hash
from handradar.synthesis.providers import synthesize_source
from handradar.tasks.classify import evaluate

if TYPE_CHECKING:
    from handradar.tasks.train import Job

log = logging.getLogger(__name__)

MEASURED_VARIANTS = ("radar_only", "model_synth", "model_synth_only", "synth_pretrain")


def measured_split(labels: np.ndarray, splits: np.ndarray, *, train: str, per_class: int | str, val_per_class: int,
                   seed: int, test_seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(training rows, validation rows) of the ``train`` split: ``val_per_class`` rows per class drawn with
    ``test_seed`` (the same for every seed and K), then ``per_class`` of the rest drawn with ``seed``, nested
    across K (``all``: every one); a class left with no validation or training row is an error."""
    train_rows, val_rows = [], []
    pool = np.flatnonzero(splits == train)
    for c in np.unique(labels[pool]):
        members = np.sort(pool[labels[pool] == c])
        val = _class_permutation(members, test_seed, c)[:val_per_class]
        rest = np.setdiff1d(members, val)
        if len(val) < val_per_class or (per_class != 0 and not len(rest)):
            raise TooFewRows(f"class {c} has {len(members)} rows in split {train!r}: too few for {val_per_class} "
                             "validation rows and at least 1 training row (split.val_per_class)")
        k = len(rest) if per_class == "all" else int(per_class)
        train_rows.append(_class_permutation(rest, seed, c)[:k])
        val_rows.append(val)
    return np.sort(np.concatenate(train_rows)), np.sort(np.concatenate(val_rows))


def synthesize_measured(real_path: Path, values: dict, *, per_class: int, seed: int, cache_dir: Path,
                        sim: dict | None) -> Path:
    """Synthetic rows of the dataset's classes from their motions (cached by everything that makes them);
    Doppler mirrored when ``values["approaching"]`` is ``low`` (the dataset's approaching end)."""
    attrs = read_attrs(real_path)
    m = Manifest.from_dict(json.loads(attrs["manifest"]), real_path)  # as the file was built: the manifest may have moved
    shape = (attrs["chain"].stft_len, attrs["chain"].n_columns)
    radar = synthesis_radar(m, shape, values)
    chain = dataset_chain(m, shape)
    if values.get("dynamic_range_db") is not None:
        chain = type(chain)(**{**chain.__dict__, "dynamic_range_db": float(values["dynamic_range_db"])})
    duration = shape[1] * radar.frame_period_s
    source = {"name": "motions", "classes": m.classes, "per_class": int(per_class), "seed": int(seed),
              "duration_s": duration, "ranges": {k: list(v) for k, v in m.motion_ranges.items()}}
    out = Path(cache_dir) / f"measured-synth-{config_hash(source, radar, chain, sim, values, 'measured/1')}.h5"
    if not out.is_file():
        log.info("synthesising %d rows per class of %d classes (v_max %.2f m/s, %.1f ms per column)", per_class,
                 len(m.classes), radar.max_velocity_m_s, radar.frame_period_s * 1e3)
        synthesize_source(source, out, radar=radar, chain=chain, sim=sim, cache_dir=Path(cache_dir) / "profiles",
                          progress=False)
    if values.get("approaching", "high") == "low":
        mirrored = out.with_name(out.stem + "-mirrored.h5")
        if not mirrored.is_file():
            mirror_file(out, mirrored)
        out = mirrored
    return out


def mirror_doppler(x: np.ndarray) -> np.ndarray:
    """Spectrograms (..., doppler, columns) with the Doppler axis mirrored about the zero row ``doppler // 2``."""
    n = x.shape[-2]
    return np.roll(x[..., ::-1, :], 1 - n % 2, axis=-2)


def mirror_file(src: Path, dst: Path) -> None:
    """A copy of dataset file ``src`` at ``dst`` with every spectrogram Doppler-mirrored (atomically)."""
    with atomic_path(dst) as tmp:
        shutil.copyfile(src, tmp)
        with h5py.File(tmp, "r+") as h5:
            h5["spectrograms"][...] = mirror_doppler(h5["spectrograms"][()])
            h5.attrs["doppler"] = "mirrored"


def run_measured(job: Job) -> dict[str, float]:
    """The job kind ``handradar.tasks.measured.run_measured`` (see the module docstring)."""
    cfg, real = job.cfg, job.real
    attrs = read_attrs(real.path)
    if attrs.get("skeletons") != "none" or "manifest" not in attrs:
        raise FormatError(real.path, "the measured job needs a measured dataset (data=measured data.manifest=FILE)")
    manifest = json.loads(attrs["manifest"])
    split_of = real.meta["split"]
    per_class = cfg.split.per_class
    per_class = "all" if str(per_class) == "all" else int(per_class)
    train, val = measured_split(real.y, split_of, train=manifest["train"], per_class=per_class,
                                val_per_class=int(cfg.split.val_per_class), seed=job.seed,
                                test_seed=int(cfg.split.get("test_seed", 0)))
    tests = {s: np.flatnonzero(split_of == s) for s in manifest["test"]}
    job.tracker.log_params({"split_sizes.train": len(train), "split_sizes.val": len(val),
                            **{f"split_sizes.test_{s}": len(r) for s, r in tests.items()}})
    names = [v for v in cfg.variants if v in MEASURED_VARIANTS]
    unknown = sorted(set(cfg.variants) - set(MEASURED_VARIANTS))
    if unknown:
        raise ValueError(f"unknown measured variant {unknown[0]!r}; choose from {list(MEASURED_VARIANTS)}")
    if per_class == 0:
        names = [v for v in names if v == "model_synth_only"]
    n_classes = len(real.classes)
    synth_cfg = cfg.synth.measured
    values = {k: v for k, v in OmegaConf.to_container(synth_cfg.unknowns, resolve=True).items() if v not in (None, UNKNOWN)}
    synthetic: Path | None = None
    if any(v != "radar_only" for v in names):
        synthetic = synthesize_measured(real.path, values, per_class=int(synth_cfg.per_class), seed=job.seed,
                                        cache_dir=Path(cfg.synth.cache_dir),
                                        sim=OmegaConf.to_container(cfg.sim, resolve=True))
        synth_y = load_arrays(synthetic).y
        if not np.array_equal(np.unique(synth_y), np.arange(n_classes)):
            raise FormatError(synthetic, "synthetic rows do not cover every class of the dataset")

    def score(net) -> dict:
        out = {}
        for part, rows in [("val", val), *tests.items()]:
            acc, cm = evaluate(net, real.x[rows], real.y[rows], n_classes, device=job._eval_device())
            out[part] = {"acc": acc, "confusion": cm.tolist()}
        return out

    results = {}
    for name in names:
        def compute(name: str = name) -> dict:
            real_part = [FileRows(real.path, train)] if len(train) else []
            synth_part = [FileRows(synthetic)] if synthetic is not None else []
            if name == "synth_pretrain":
                pre = job.fit_classifier(f"{name}_pretrain", synth_part, n_classes)
                net = job.fit_classifier(name, real_part, n_classes, init=backbone_state(pre.cpu()))
            else:
                parts = {"radar_only": real_part, "model_synth": real_part + synth_part, "model_synth_only": synth_part}[name]
                net = job.fit_classifier(name, parts, n_classes)
            return {"scores": score(net), "n_real": int(len(train)), "classes": real.classes}

        results[name] = job.cached(name, compute)
        r = results[name]["scores"]
        log.info("%s: validation %.3f; %s", name, r["val"]["acc"],
                 ", ".join(f"test {s} {r[s]['acc']:.3f}" for s in tests))
    metrics = {}
    for name, res in results.items():
        metrics[f"val/acc_{name}"] = res["scores"]["val"]["acc"]
        for s in tests:
            metrics[f"test/acc_{name}_{s}"] = res["scores"][s]["acc"]
    return metrics
