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
- ``model_synth``: the K real rows + the synthetic rows (``synth.measured.real_share``: the real rows' share of
  every batch; null: their share of the rows);
- ``model_synth_only``: the synthetic rows alone (K = 0 is this variant alone); with ``synth.measured.adapt_bn``
  its BatchNorm statistics are then recomputed on the measured rows the fit sees, unlabelled (AdaBN);
- ``synth_pretrain``: trained on the synthetic rows, then fine-tuned on the K real rows.

Metrics: ``val/acc_<variant>`` and ``test/acc_<variant>_<split>`` for each test split. The run folder also holds
the unpaired gap report of the synthetic rows against the measured rows the fit saw (handradar.gap.unpaired).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

from handradar.atomic import atomic_path, atomic_write_text
from handradar.data.datamodule import FileRows
from handradar.data.datasets import load_arrays
from handradar.data.measured import UNKNOWN
from handradar.data.splits import measured_split
from handradar.errors import FormatError
from handradar.gap.unpaired import write_unpaired_gap
from handradar.models.classifiers import backbone_state
from handradar.provenance import config_hash
from handradar.synthesis.measured import (
    DEEP_FLOOR_DB,
    OBJECTIVES,
    UnknownsFit,
    fit_unknowns,
    measured_manifest,
    synthesize_measured,
)
from handradar.tasks.classify import evaluate, recompute_bn_stats

if TYPE_CHECKING:
    from handradar.tasks.train import Job

log = logging.getLogger(__name__)

MEASURED_VARIANTS = ("radar_only", "model_synth", "model_synth_only", "synth_pretrain")


def fitted_unknowns(job: Job, fit_rows: np.ndarray) -> dict:
    """The manifest's unknowns: set in ``synth.measured.unknowns``, else fitted (unpaired, :func:`fit_unknowns`) on
    ``fit_rows``; the fit is cached under the synthesis cache and logged (``synth.fitted.*``)."""
    cfg = job.cfg.synth.measured
    m, _ = measured_manifest(job.real.path)
    given = {k: v for k, v in OmegaConf.to_container(cfg.unknowns, resolve=True).items() if v is not None}
    fit = OmegaConf.to_container(cfg.fit, resolve=True)
    grid = {}
    for k, candidates in fit["grid"].items():
        if k in given:
            grid[k] = [given[k]]
        elif k == "approaching":  # rows of a manifest that states it are already in the project's orientation
            grid[k] = list(candidates) if m.approaching == UNKNOWN else ["high"]
        elif k in m.radar:
            grid[k] = list(candidates) if m.radar[k] == UNKNOWN else [m.radar[k]]
        else:  # the receiver noise floor: no manifest field, a nuisance of the synthetic rows
            grid[k] = list(candidates)
    if all(len(v) == 1 for v in grid.values()):
        return {k: v[0] for k, v in grid.items()}
    sim = OmegaConf.to_container(job.cfg.sim, resolve=True)
    key = config_hash(grid, fit, sim, job.real.path.name, fit_rows.tolist())
    out = Path(job.cfg.synth.cache_dir) / f"measured-fit-{key}.json"
    if out.is_file():
        result = json.loads(out.read_text())
    else:
        n_classes = len(job.real.classes)

        def simulate(radar: dict) -> tuple[np.ndarray, np.ndarray] | None:
            values = {k: v for k, v in radar.items() if v is not None}
            try:
                path = synthesize_measured(job.real.path, {**values, "dynamic_range_db": DEEP_FLOOR_DB},
                                           per_class=int(fit["per_class"]), seed=int(fit["seed"]),
                                           cache_dir=Path(job.cfg.synth.cache_dir), sim=sim)
            except ValueError as exc:  # chirps that do not fit in the frame: no candidate
                log.info("fit: %s skipped (%s)", ", ".join(f"{k} {v:g}" for k, v in values.items()), exc)
                return None
            d = load_arrays(path)
            return d.x, d.y

        log.info("fitting %s on %d measured rows (unpaired: %s)", ", ".join(k for k, v in grid.items() if len(v) > 1),
                 len(fit_rows), OBJECTIVES[str(fit.get("objective", "means"))])
        result = fit_unknowns(job.real.x[fit_rows], job.real.y[fit_rows], n_classes, simulate, grid,
                              n_boot=int(fit["n_boot"]), seed=int(fit["seed"]),
                              objective=str(fit.get("objective", "means"))).as_dict()
        atomic_write_text(out, json.dumps(result, indent=1))
    log.info("fitted: %s", UnknownsFit.from_dict(result).summary())
    job.tracker.log_params({f"synth.fitted.{k}": v for k, v in result["values"].items()})
    job.tracker.log_artifact(out, "synthesis")
    return result["values"]


def run_measured(job: Job) -> dict[str, float]:
    """The job kind ``handradar.tasks.measured.run_measured`` (see the module docstring)."""
    cfg, real = job.cfg, job.real
    m, _ = measured_manifest(real.path)
    split_of = real.meta["split"]
    per_class = cfg.split.per_class
    per_class = "all" if str(per_class) == "all" else int(per_class)
    split = dict(train=m.train, val_per_class=int(cfg.split.val_per_class), test_seed=int(cfg.split.get("test_seed", 0)))
    train, val = measured_split(real.y, split_of, per_class=per_class, seed=job.seed, **split)
    tests = {s: np.flatnonzero(split_of == s) for s in m.test}
    job.tracker.log_params({"split_sizes.train": len(train), "split_sizes.val": len(val),
                            **{f"split_sizes.test_{s}": len(r) for s, r in tests.items()}})
    unknown = sorted(set(cfg.variants) - set(MEASURED_VARIANTS))
    if unknown:
        raise ValueError(f"unknown measured variant {unknown[0]!r}; choose from {list(MEASURED_VARIANTS)}")
    names = [v for v in cfg.variants if per_class != 0 or v == "model_synth_only"]
    n_classes = len(real.classes)
    synthetic: Path | None = None
    if any(v != "radar_only" for v in names):
        fit_on = str(cfg.synth.measured.fit.rows)
        if fit_on not in ("pool", "train"):
            raise ValueError(f"synth.measured.fit.rows must be pool or train, found {fit_on!r}")
        fit_rows = train if fit_on == "train" else measured_split(real.y, split_of, per_class="all", seed=0, **split)[0]
        values = fitted_unknowns(job, fit_rows)
        synthetic = synthesize_measured(real.path, values, per_class=int(cfg.synth.measured.per_class), seed=job.seed,
                                        cache_dir=Path(cfg.synth.cache_dir),
                                        sim=OmegaConf.to_container(cfg.sim, resolve=True))
        synth = load_arrays(synthetic)
        if not np.array_equal(np.unique(synth.y), np.arange(n_classes)):
            raise FormatError(synthetic, "synthetic rows do not cover every class of the dataset")
        if job.rank_zero:  # where synthetic differs from the measured rows the fit saw (unpaired)
            for f in write_unpaired_gap(real.x[fit_rows], real.y[fit_rows], synth.x, synth.y, real.classes, job.run_dir):
                job.tracker.log_artifact(f, "unpaired_gap")

    def score(net) -> dict:
        out = {}
        for part, rows in [("val", val), *tests.items()]:
            acc, cm = evaluate(net, real.x[rows], real.y[rows], n_classes, device=job._eval_device())
            out[part] = {"acc": acc, "confusion": cm.tolist()}
        return out

    real_share = cfg.synth.measured.get("real_share")
    if real_share is not None and not 0.0 < float(real_share) < 1.0:
        raise ValueError(f"synth.measured.real_share must lie in (0, 1) or be null, found {real_share}")
    real_share = None if real_share is None else float(real_share)
    real_part = [FileRows(real.path, train)] if len(train) else []
    synth_part = [FileRows(synthetic)] if synthetic is not None else []

    def synthetic_only():
        """The classifier of the synthetic rows alone (``model_synth_only``, and where ``synth_pretrain`` starts): it
        depends on the synthetic rows, the seed, the model and the trainer only, so it is cached beside the rows and
        shared by the jobs of every K."""
        setup = [OmegaConf.to_container(cfg[k], resolve=True) for k in ("model", "trainer")]
        key = config_hash(setup, int(cfg.data.batch_size), job.seed, n_classes)
        f = Path(cfg.synth.cache_dir) / f"{synthetic.stem}-classifier-{key}.pt"
        if f.is_file():
            net = instantiate(cfg.model.net, num_classes=n_classes)
            net.load_state_dict(torch.load(f, weights_only=True))
            return net
        net = job.fit_classifier("model_synth_only", synth_part, n_classes)
        if job.rank_zero:
            with atomic_path(f) as tmp:
                torch.save(net.state_dict(), tmp)
        return net

    results = {}
    for name in names:
        def compute(name: str = name) -> dict:
            if name == "synth_pretrain":
                net = job.fit_classifier(name, real_part, n_classes, init=backbone_state(synthetic_only().cpu()))
            elif name == "model_synth_only":
                net = synthetic_only()
                if cfg.synth.measured.get("adapt_bn") and len(fit_rows):
                    # AdaBN (Li et al. 2018): BatchNorm statistics of the unlabelled measured rows the fit sees
                    recompute_bn_stats(net, real.x[fit_rows], device=job._eval_device())
                    log.info("%s: BatchNorm statistics of %d unlabelled measured rows", name, len(fit_rows))
            elif name == "model_synth" and real_share is not None and real_part:
                net = job.fit_classifier(name, real_part + synth_part, n_classes, shares=[real_share, 1.0 - real_share])
            else:
                net = job.fit_classifier(name, real_part + (synth_part if name == "model_synth" else []), n_classes)
            return {"scores": score(net), "n_real": int(len(train)), "classes": real.classes}

        results[name] = job.cached(name, compute)
        r = results[name]["scores"]
        log.info("%s: validation %.3f; %s", name, r["val"]["acc"], ", ".join(f"test {s} {r[s]['acc']:.3f}" for s in tests))
    metrics = {}
    for name, res in results.items():
        metrics[f"val/acc_{name}"] = res["scores"]["val"]["acc"]
        for s in tests:
            metrics[f"test/acc_{name}_{s}"] = res["scores"][s]["acc"]
    return metrics
