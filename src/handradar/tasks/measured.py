"""The measured-radar job (``python train.py +experiment=measured data.manifest=FILE split.per_class=K``).

A measured spectrogram dataset (handradar.data.measured: no skeletons) is split by its manifest:
training rows come from its ``train`` split, of which ``split.val_per_class`` rows per class
(fixed, ``split.test_seed``) are the validation rows every setting is chosen on; ``split.per_class``
rows per class (nested across K for one seed; ``all``: every other training row; 0: none) train the
classifiers. Each ``test`` split (held-out users) is only reported.

The labelled budget: a job at K rows per class uses the labels of those K rows and of no other measured row.
The training users' other rows outside validation (the *unlabelled pool*) serve through statistics that ignore
their class only: the unpaired fit of the manifest's unknowns (``synth.measured.fit.rows=unlabelled``, pooled
images) and AdaBN. ``fit.rows=labelled`` fits class by class on the K rows instead. Each variant's budget is
logged (``budget.<variant>.labelled`` / ``.unlabelled``: row counts).

Synthetic rows come from the motion library (handradar.hand.motions) through the classes' motions,
simulated with the radar and chain that reproduce the dataset's processing
(:func:`handradar.synthesis.measured.synthesis_radar`, frame-based Doppler) at the manifest's known values
and ``synth.measured`` for its unknowns. Variants (handradar.vocab.MEASURED_VARIANTS), all trained by the same
network (``model``) and training recipe (``recipe``), so that a difference between them comes from the data:

- ``radar_only``: the K real rows;
- ``model_synth``: the K real rows + the synthetic rows (``synth.measured.real_share``: the real rows' share of
  every batch; null: their share of the rows);
- ``model_synth_only``: the synthetic rows alone (K = 0 is this variant alone); with ``synth.measured.adapt_bn``
  its BatchNorm statistics are then recomputed on the unlabelled pool (AdaBN);
- ``synth_pretrain``: trained on the synthetic rows, then fine-tuned on the K real rows.

Metrics: ``val/acc_<variant>`` and ``test/acc_<variant>_<split>`` for each test split; the parameters
``measured.per_class``, ``measured.variants`` and ``measured.tests`` say which (handradar.runs.tables reads them).
The run folder holds each variant's confusion matrix on validation and on each test split
(``figures/confusion_<variant>_<split>.png``), and the unpaired gap report of the synthetic rows against the pool
(handradar.gap.unpaired: a report that chooses nothing), naming per class the processing step that, switched on
alone, explains most of the difference.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from handradar.atomic import atomic_path, atomic_write_text
from handradar.data.datamodule import FileRows
from handradar.data.datasets import load_arrays
from handradar.data.measured import dataset_chain, measured_manifest
from handradar.data.unknowns import MOTION, UNKNOWN, UNKNOWNS
from handradar.hand.motions import library_key
from handradar.data.splits import measured_split
from handradar.errors import FormatError
from handradar.gap.unpaired import write_unpaired_gap
from handradar.models.classifiers import backbone_state
from handradar.provenance import config_hash
from handradar.synthesis.measured import (
    FIT_VERSION,
    OBJECTIVES,
    UnknownsFit,
    fit_unknowns,
    motion_ranges,
    step_rows,
    synthesize_measured,
)
from handradar.tasks.classify import evaluate, recompute_bn_stats
from handradar.tasks.train import Job, job_hash
from handradar.viz.confusion import plot_confusion
from handradar.vocab import MEASURED_VARIANTS

log = logging.getLogger(__name__)

FIT_ROWS = {  # synth.measured.fit.rows: what the unpaired fit compares, within the labelled budget
    "unlabelled": "pooled images of the training users' rows outside validation, labels ignored",
    "labelled": "class images of the job's K labelled rows per class",
}


@dataclass(frozen=True)
class MeasuredSetup:
    """A measured job's settings, checked as a whole before any fit or synthesis (:meth:`from_cfg`)."""

    per_class: int | str       # K: real training rows per class, or "all"
    val_per_class: int
    test_seed: int
    variants: tuple[str, ...]  # those that run at this K (K = 0: model_synth_only alone)
    fit_rows: str              # FIT_ROWS
    real_share: float | None
    adapt_bn: bool
    synth_per_class: int

    @classmethod
    def from_cfg(cls, cfg: DictConfig) -> MeasuredSetup:
        raw = str(cfg.split.per_class)
        if raw != "all" and not (raw.isdigit() and int(raw) >= 0):
            raise ValueError(f"split.per_class must be a count >= 0 or all, found {raw!r}")
        per_class = "all" if raw == "all" else int(raw)
        unknown = [v for v in cfg.variants if v not in MEASURED_VARIANTS]
        if unknown:
            raise ValueError(f"unknown measured variant {unknown[0]!r}; choose from {list(MEASURED_VARIANTS)}")
        m = cfg.synth.measured
        fit_rows, objective = str(m.fit.rows), str(m.fit.get("objective", "means"))
        if fit_rows not in FIT_ROWS:
            raise ValueError(f"synth.measured.fit.rows must be one of {list(FIT_ROWS)}, found {fit_rows!r}")
        if objective not in OBJECTIVES:
            raise ValueError(f"synth.measured.fit.objective must be one of {list(OBJECTIVES)}, found {objective!r}")
        if fit_rows == "labelled" and per_class == 0:
            raise ValueError("synth.measured.fit.rows=labelled fits on the job's K labelled rows, and K = 0 has none: "
                             "use fit.rows=unlabelled (label-free)")
        real_share = m.get("real_share")
        if real_share is not None and not 0.0 < float(real_share) < 1.0:
            raise ValueError(f"synth.measured.real_share must lie in (0, 1) or be null, found {real_share}")
        if int(m.per_class) < 1:
            raise ValueError(f"synth.measured.per_class must be >= 1, found {m.per_class}")
        for where in ("unknowns", "fit.grid"):
            extra = sorted(set(OmegaConf.select(m, where)) - set(UNKNOWNS))
            if extra:
                raise ValueError(f"synth.measured.{where}.{extra[0]} is no unknown; expected one of {list(UNKNOWNS)}")
        return cls(per_class=per_class, val_per_class=int(cfg.split.val_per_class),
                   test_seed=int(cfg.split.get("test_seed", 0)),
                   variants=tuple(v for v in cfg.variants if per_class != 0 or v == "model_synth_only"),
                   fit_rows=fit_rows, real_share=None if real_share is None else float(real_share),
                   adapt_bn=bool(m.get("adapt_bn")), synth_per_class=int(m.per_class))

    @property
    def synthetic(self) -> bool:
        """Whether any variant needs the synthetic rows, or none runs (``variants=[]``: the fit, the synthetic rows
        and the unpaired gap report alone, a quick look while setting a manifest's ranges)."""
        return not self.variants or any(v != "radar_only" for v in self.variants)


@dataclass(frozen=True)
class MeasuredRows:
    """Row indices into the measured dataset: the K labelled training rows, the validation rows, the unlabelled pool
    (every training-user row outside validation, the K rows included) and each test split's."""

    train: np.ndarray
    val: np.ndarray
    pool: np.ndarray
    tests: dict[str, np.ndarray]


def measured_rows(job: Job, setup: MeasuredSetup) -> MeasuredRows:
    """The job's rows (:class:`MeasuredRows`), their sizes logged."""
    real = job.real
    m, _ = measured_manifest(real.path)
    split_of = real.meta["split"]
    common = dict(train=m.train, val_per_class=setup.val_per_class, test_seed=setup.test_seed, classes=real.classes)
    train, val = measured_split(real.y, split_of, per_class=setup.per_class, seed=job.seed, **common)
    pool = measured_split(real.y, split_of, per_class="all", seed=0, **common)[0]
    rows = MeasuredRows(train=train, val=val, pool=pool, tests={s: np.flatnonzero(split_of == s) for s in m.test})
    job.log_params({"split_sizes.train": len(train), "split_sizes.val": len(val), "split_sizes.pool": len(pool),
                    **{f"split_sizes.test_{s}": len(r) for s, r in rows.tests.items()}})
    return rows


def label_budget(setup: MeasuredSetup, rows: MeasuredRows) -> dict[str, dict[str, int]]:
    """Per variant, how many measured rows it uses with their labels and without (the pool, through the fit's
    pooled images or AdaBN; counted even where every unknown is set and nothing is fitted); validation and test
    rows are counted in neither: they train nothing."""
    k, pool = len(rows.train), len(rows.pool)
    fit_labelled = setup.fit_rows == "labelled"
    fit = {"labelled": k if fit_labelled else 0, "unlabelled": 0 if fit_labelled else pool}
    out = {"radar_only": {"labelled": k, "unlabelled": 0},
           "model_synth": {"labelled": k, "unlabelled": fit["unlabelled"]},
           "synth_pretrain": {"labelled": k, "unlabelled": fit["unlabelled"]},
           "model_synth_only": {"labelled": fit["labelled"],
                                "unlabelled": pool if setup.adapt_bn or not fit_labelled else 0}}
    return {v: out[v] for v in setup.variants}


def fitted_unknowns(job: Job, x: np.ndarray, y: np.ndarray | None) -> dict:
    """The manifest's unknowns: set in ``synth.measured.unknowns``, else fitted (unpaired, :func:`fit_unknowns`) on
    the measured rows ``x``: class by class with their labels ``y``, or pooled (``y`` None: label-free, one image of
    all rows against one of all synthetic rows). Candidates: ``synth.measured.fit.grid``, else the unknown's default
    grid (handradar.data.unknowns); the motion unknowns only with ``synth.measured.fit.motions`` (else their prior,
    the manifest's ``motion_ranges``, as it is). The fit is cached under the synthesis cache and logged
    (``synth.fitted.*``); a value at the edge of its grid is logged as a warning."""
    cfg = job.cfg.synth.measured
    m, shape = measured_manifest(job.real.path)
    given = {k: v for k, v in OmegaConf.to_container(cfg.unknowns, resolve=True).items() if v is not None}
    fit = OmegaConf.to_container(cfg.fit, resolve=True)
    grid = {}
    for name, u in UNKNOWNS.items():
        if name in given:
            grid[name] = [given[name]]
        elif (stated := m.value_of(name)) != UNKNOWN:
            grid[name] = [stated]
        elif u.stage == "motion" and not fit.get("motions"):
            grid[name] = [u.identity]  # the motions' prior as it is, unless fit.motions asks
        else:
            grid[name] = list(fit["grid"].get(name, u.grid))
    if all(len(v) == 1 for v in grid.values()):
        return {k: v[0] for k, v in grid.items()}
    pooled = y is None
    labels = np.zeros(len(x), dtype=np.int64) if pooled else y
    n_classes = 1 if pooled else len(job.real.classes)
    sim = OmegaConf.to_container(job.cfg.sim, resolve=True)
    processing = dataset_chain(m, shape)  # the steps the manifest states; the fit's values go over them
    key = config_hash(grid, fit, sim, processing, job.real.path.name, x.shape, float(x.sum(dtype=np.float64)),
                      labels.tolist(), library_key(), FIT_VERSION)
    out = Path(job.cfg.synth.cache_dir) / f"measured-fit-{key}.json"
    if out.is_file():
        result = json.loads(out.read_text())
    else:

        def simulate(radar: dict) -> tuple[np.ndarray, np.ndarray] | None:
            values = {k: v for k, v in radar.items() if v is not None}
            try:
                path = synthesize_measured(job.real.path, values, per_class=int(fit["per_class"]), seed=int(fit["seed"]),
                                           cache_dir=Path(job.cfg.synth.cache_dir), sim=sim, finish=False)
            except ValueError as exc:  # chirps that do not fit in the frame: no candidate
                log.info("fit: %s skipped (%s)", ", ".join(f"{k} {v}" for k, v in values.items()
                                                          if k not in MOTION or not UNKNOWNS[k].keeps_prior(v)), exc)
                return None
            d = load_arrays(path)
            return d.x, np.zeros_like(d.y) if pooled else d.y

        log.info("fitting %s on %d measured rows (unpaired, %s: %s)", ", ".join(k for k, v in grid.items() if len(v) > 1),
                 len(x), "label-free" if pooled else "class by class", OBJECTIVES[str(fit["objective"])])
        result = fit_unknowns(x, labels, n_classes, simulate, grid, n_boot=int(fit["n_boot"]), seed=int(fit["seed"]),
                              objective=str(fit["objective"]), processing=processing).as_dict()
        atomic_write_text(out, json.dumps(result, indent=1))
    summary = UnknownsFit.from_dict(result)
    (log.warning if summary.edges else log.info)("fitted: %s", summary.summary())
    shared, _ = motion_ranges(m, result["values"])
    moved = [UNKNOWNS[k].motion for k in MOTION if k in result["values"]
             and not UNKNOWNS[k].keeps_prior(result["values"][k])]
    if moved:
        log.info("motions drawn from the fitted ranges: %s",
                 ", ".join(f"{k} {shared[k][0]:g}-{shared[k][1]:g}" for k in moved))
    job.log_params({f"synth.fitted.{k}": v for k, v in result["values"].items()})
    job.tracker.log_artifact(out, "synthesis")
    return result["values"]


def synthetic_rows(job: Job, setup: MeasuredSetup, rows: MeasuredRows) -> Path:
    """The synthetic rows of the job (the unknowns fitted within the budget first), checked to cover every class,
    with the unpaired gap report against the pool written beside the run."""
    real, cfg = job.real, job.cfg
    if setup.fit_rows == "labelled":
        values = fitted_unknowns(job, real.x[rows.train], real.y[rows.train])
    else:
        values = fitted_unknowns(job, real.x[rows.pool], None)
    made = dict(per_class=setup.synth_per_class, seed=job.seed, cache_dir=Path(cfg.synth.cache_dir),
                sim=OmegaConf.to_container(cfg.sim, resolve=True))
    path = synthesize_measured(real.path, values, **made)
    synth = load_arrays(path)
    if not np.array_equal(np.unique(synth.y), np.arange(len(real.classes))):
        raise FormatError(path, "synthetic rows do not cover every class of the dataset")
    if job.rank_zero:  # where synthetic differs from the measured rows, and which step explains it (chooses nothing)
        steps = step_rows(real.path, values, **made)
        for f in write_unpaired_gap(real.x[rows.pool], real.y[rows.pool], synth.x, synth.y, real.classes, job.run_dir,
                                    steps, approaching=str(values.get("approaching") or "high")):
            job.tracker.log_artifact(f, "unpaired_gap")
    return path


def synthetic_only(job: Job, synthetic: Path) -> torch.nn.Module:
    """The classifier of the synthetic rows alone (``model_synth_only``, and where ``synth_pretrain`` starts): it
    depends on the synthetic rows, the seed, the model, the recipe and the trainer only, so it is cached beside the
    rows and shared by the jobs of every K."""
    cfg, n_classes = job.cfg, len(job.real.classes)
    setup = [OmegaConf.to_container(cfg[k], resolve=True) for k in ("model", "recipe", "trainer")]
    key = config_hash(setup, int(cfg.data.batch_size), job.seed, n_classes)
    f = Path(cfg.synth.cache_dir) / f"{synthetic.stem}-classifier-{key}.pt"
    if f.is_file():
        net = instantiate(cfg.model.net, num_classes=n_classes)
        net.load_state_dict(torch.load(f, weights_only=True))
        return net
    net = job.fit_classifier("model_synth_only", [FileRows(synthetic)], n_classes)
    if job.rank_zero:
        with atomic_path(f) as tmp:
            torch.save(net.state_dict(), tmp)
    return net


def train_variant(job: Job, name: str, setup: MeasuredSetup, rows: MeasuredRows,
                  synthetic: Path | None) -> torch.nn.Module:
    """One variant's classifier (module docstring), by the job's model and recipe."""
    real, n_classes = job.real, len(job.real.classes)
    real_part = [FileRows(real.path, rows.train)] if len(rows.train) else []
    synth_part = [FileRows(synthetic)] if synthetic is not None else []
    if name == "radar_only":
        return job.fit_classifier(name, real_part, n_classes)
    if name == "synth_pretrain":
        return job.fit_classifier(name, real_part, n_classes, init=backbone_state(synthetic_only(job, synthetic).cpu()))
    if name == "model_synth_only":
        net = synthetic_only(job, synthetic)
        if setup.adapt_bn:  # AdaBN (Li et al. 2018): BatchNorm statistics of the unlabelled pool
            recompute_bn_stats(net, real.x[rows.pool], device=job.eval_device())
            log.info("%s: BatchNorm statistics of %d unlabelled measured rows", name, len(rows.pool))
        return net
    shares = None if setup.real_share is None else [setup.real_share, 1.0 - setup.real_share]
    return job.fit_classifier(name, real_part + synth_part, n_classes, shares=shares)


def score(job: Job, net: torch.nn.Module, rows: MeasuredRows) -> dict:
    """Accuracy and confusion matrix on the validation rows and each test split."""
    out = {}
    for part, r in [("val", rows.val), *rows.tests.items()]:
        acc, cm = evaluate(net, job.real.x[r], job.real.y[r], len(job.real.classes), device=job.eval_device())
        out[part] = {"acc": acc, "confusion": cm.tolist()}
    return out


def setting_hash(cfg: DictConfig) -> str:
    """The job's setting: its config hash (handradar.tasks.train.job_hash) without its seed and K, 8 hex digits; the
    tables keep rows of different settings apart."""
    return job_hash(OmegaConf.merge(cfg, {"seed": 0, "split": {"per_class": 0}}), "")[:8]


def run_measured(job: Job) -> dict[str, float]:
    """The job kind ``handradar.tasks.measured.run_measured`` (see the module docstring)."""
    setup = MeasuredSetup.from_cfg(job.cfg)
    rows = measured_rows(job, setup)
    budget = label_budget(setup, rows)
    job.log_params({"measured.per_class": setup.per_class, "measured.setting": setting_hash(job.cfg),
                            "measured.variants": ",".join(setup.variants),
                            "measured.tests": ",".join(rows.tests),
                            **{f"budget.{v}.{k}": n for v, b in budget.items() for k, n in b.items()}})
    synthetic = synthetic_rows(job, setup, rows) if setup.synthetic else None
    if not setup.variants:
        log.info("no variant to train: the fit, the synthetic rows and the unpaired gap report alone (%s)",
                 job.run_dir / "unpaired_gap.md")
    metrics = {}
    for name in setup.variants:
        result = job.cached(name, lambda name=name: {"scores": score(job, train_variant(job, name, setup, rows, synthetic),
                                                                     rows),
                                                     "n_real": int(len(rows.train)), "classes": job.real.classes})
        r = result["scores"]
        log.info("%s: validation %.3f; %s", name, r["val"]["acc"], ", ".join(f"test {s} {r[s]['acc']:.3f}" for s in rows.tests))
        if job.rank_zero:  # which classes each variant confuses, on validation and each test split
            for part, scores in r.items():
                png = plot_confusion(np.asarray(scores["confusion"]), job.real.classes,
                                     job.run_dir / "figures" / f"confusion_{name}_{part}.png",
                                     title=f"{name}, K = {setup.per_class}, {part}, seed {job.seed}")
                job.tracker.log_artifact(png, "figures")
        metrics[f"val/acc_{name}"] = r["val"]["acc"]
        metrics.update({f"test/acc_{name}_{s}": r[s]["acc"] for s in rows.tests})
    return metrics
