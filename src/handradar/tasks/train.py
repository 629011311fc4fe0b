"""The train.py job: few-shot / OOD variants and external pre-training, resumable, logged to MLflow.

A job (one composed config, one seed) trains several classifiers ("variants") and writes:

- ``<run_dir>/metrics.json``: flat ``{"test/acc_<variant>": accuracy in [0, 1]}``;
- ``<run_dir>/confusion/<variant>.json`` and ``<run_dir>/figures/confusion_<variant>.png``;
- ``<run_dir>/figures/summary.png`` (variants jobs): accuracy by variant, real vs synthetic spectrograms;
- one MLflow run with the resolved config (params + ``config.yaml``), tags (preset, seed, code
  version, data hash, job hash, run dir), per-epoch training metrics ``<variant>/train/*``, the
  final metrics and the figures.

Job kinds (``job``): ``variants`` trains one classifier per entry of ``variants`` (``VARIANTS``):
``radar_only`` (the real training rows of the split), ``model_synth`` / ``enhanced_synth`` (the
same + one synthetic spectrogram per pool row, i.e. every non-test skeleton, from ``synth.provider``
in mode ``model`` / ``enhanced``), ``cgan`` (the same + CGAN samples, as many per class as the pool
has rows); the transfer variants ``model_synth_only`` / ``synth_only`` train on those synthetic
spectrograms alone (train on synthetic, test on real) and ``radar_pool`` on the pool's real
spectrograms (their upper reference). The simulator behind the synthetic variants is fitted on the
split's real training rows first (``synth.fit_sim``, the closed loop: :meth:`Job.fitted_sim` through
handradar.gap.job.fit_simulator), optionally drawn ``synth.samples_per_row`` times around its fitted
nuisance parameters (``synth.randomize``, :func:`nuisance_draw`). ``external_pretrain`` pre-trains on
``synth.external_provider`` data, simulated with the simulator fitted on the smallest fraction's rows,
and fine-tunes on few-shot fractions of class subsets, against the same training from scratch; one
split per fraction, restricted to each subset's classes, so the fit's rows train every fine-tune.
Any other job kind is a dotted function name ``fn(job: Job) -> {metric name: number}`` (e.g. a
synthesis-fit job): it gets the loaded real data (``job.real``), the state folder (``job.state``, for resumable work), the
tracker and ``job.cfg``, and its metrics go to metrics.json and MLflow like the built-in kinds.

Progress: each stage (the data, what the variants add, each variant, the summary) is announced on
the log with its number, the elapsed time and the next stage (handradar.runs.progress).

Resuming: the job's state (checkpoints, finished variants, CGAN samples, the MLflow run id) lives
in ``<state_dir>/<job hash>``; the hash covers the config (paths, logging and caches excluded) and
the real data's hash. Re-running the same command after an interruption resumes every fit from
its last epoch checkpoint, skips finished variants and completes the same MLflow run.
``resume=false`` discards that state.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import lightning.pytorch as pl
import numpy as np
import torch
from hydra.utils import instantiate
from lightning.fabric.utilities.rank_zero import rank_zero_only
from omegaconf import DictConfig, OmegaConf

from handradar.atomic import atomic_path, atomic_write_text, file_lock
from handradar.data.datamodule import ArrayRows, FileRows, TrainingRowsDataModule
from handradar.data.datasets import (
    ArrayDataset,
    file_hash,
    import_callable,
    load_arrays,
)
from handradar.data.hdf5 import read_attrs
from handradar.data.splits import Split, few_shot_split, make_split
from handradar.errors import TooFewRows
from handradar.gap.data import load_dataset
from handradar.gap.job import fit_simulator
from handradar.gap.report import GENERIC_SETTINGS, write_report
from handradar.models.classifiers import backbone_state
from handradar.provenance import code_version, config_hash
from handradar.runs.hydra import group_choice
from handradar.runs.mlflow import DataRef, Tracker, flatten, tracked_run
from handradar.runs.progress import Stages
from handradar.runs.tables import job_table
from handradar.sim.effects import REGISTRY
from handradar.synthesis.providers import load_synthetic
from handradar.tasks.classify import ClassifierModule, evaluate, recompute_bn_stats
from handradar.tasks.gan import CGANModule, sample_per_class
from handradar.training import TrackerLogger, make_trainer, resumable_fit
from handradar.viz.confusion import plot_confusion
from handradar.viz.summary import plot_summary

log = logging.getLogger(__name__)

# variant -> (the split's real radar rows it trains on: "train", "pool" or None; what it adds:
# synthetic spectrograms of the pool's skeletons in provider mode "model" / "enhanced", CGAN samples, or nothing)
VARIANTS: dict[str, tuple[str | None, str | None]] = {
    "radar_only": ("train", None),
    "model_synth": ("train", "model"),
    "enhanced_synth": ("train", "enhanced"),
    "cgan": ("train", "cgan"),
    "model_synth_only": (None, "model"),   # train on synthetic, test on real: does synthetic stand in for real?
    "synth_only": (None, "enhanced"),
    "radar_pool": ("pool", None),          # the upper reference of the *_only variants: the pool's real rows
}
HASH_IGNORED = ("paths", "logger", "resume", "state_dir", "threads", "checkpoint_interval_s", "print_table")
# what a variant adds -> the stage that makes it (announced before the variants that train on it)
ADDITION_STAGES = {"model": "synthesis (model-based)", "enhanced": "synthesis (RadarWeightNet)", "cgan": "CGAN samples"}


def variant_names(variants: Any) -> list[str]:
    """The ``variants`` setting as a list of known variant names (``all``: every one of ``VARIANTS``)."""
    names = list(VARIANTS) if variants == "all" else list(variants)
    unknown = [n for n in names if n not in VARIANTS]
    if unknown:
        raise ValueError(f"unknown variant {unknown[0]!r}; choose from {list(VARIANTS)} or variants=all")
    return names


def job_hash(cfg: DictConfig, data_hash: str) -> str:
    """Hash of what determines a job's results: the config without paths, logging and caches,
    with the dataset locator replaced by the data's content hash."""
    c = OmegaConf.to_container(cfg, resolve=True)
    for k in HASH_IGNORED:
        c.pop(k, None)
    c.get("data", {}).pop("dataset", None)

    def strip(o: Any) -> Any:
        if isinstance(o, dict):
            return {k: strip(v) for k, v in o.items() if k != "cache_dir"}
        return [strip(v) for v in o] if isinstance(o, list) else o

    return config_hash(strip(c), data_hash)


def weights_hash(net: torch.nn.Module) -> str:
    """SHA-256 (16 hex digits) of a network's parameters and buffers: equal iff bit-identical."""
    h = hashlib.sha256()
    for k, v in sorted(net.state_dict().items()):
        h.update(k.encode())
        h.update(v.detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()[:16]


def nuisance_draw(sim: dict, spread: dict, rng: np.random.Generator) -> dict:
    """``sim`` settings with each parameter named in ``spread`` (``{rcs_exponent: sd, effect: {param: sd}}``,
    sd in the parameter's unit) drawn from a normal around its value, clipped to its bounds.
    Parameters of effects the simulator lacks are left alone."""
    out = json.loads(json.dumps(sim))  # a deep copy of plain settings
    params = out.setdefault("effect_params", {})
    flat = {f"{k}.{p}" if isinstance(v, dict) else k: sd for k, v in spread.items()
            for p, sd in (v.items() if isinstance(v, dict) else [(None, v)])}
    for name, sd in sorted(flat.items()):
        if name == "rcs_exponent":
            out[name] = float(np.clip(out.get(name, 1.0) + float(sd) * rng.standard_normal(), 0.0, 1.0))
            continue
        effect, _, key = name.partition(".")
        if effect not in REGISTRY or key not in REGISTRY[effect].params:
            raise ValueError(f"synth.randomize: {name!r} is not rcs_exponent or an effect's parameter")
        if effect not in (out.get("effects") or []):
            continue
        spec = REGISTRY[effect].params[key]
        value = float((params.get(effect) or {}).get(key, spec.default))
        params.setdefault(effect, {})[key] = float(np.clip(value + float(sd) * rng.standard_normal(), spec.low, spec.high))
    return out


def recipe_steps(recipe: Any, n_rows: int, batch_size: int) -> int | None:
    """Optimizer steps of a fit on ``n_rows`` by the training ``recipe`` (conf/recipe/): ``epochs`` passes over the
    rows in batches of ``batch_size`` (capped at the rows, as the DataModule caps it), at least ``min_steps``; None
    where the recipe counts no epochs (``trainer.max_steps`` holds)."""
    epochs = recipe.get("epochs") if recipe else None
    if epochs is None:
        return None
    if int(epochs) < 1 or n_rows < 1:
        raise ValueError(f"recipe.epochs must be >= 1 on at least one row, found {epochs} on {n_rows} rows")
    per_epoch = -(-n_rows // max(1, min(batch_size, n_rows)))
    return max(int(epochs) * per_epoch, int(recipe.get("min_steps") or 0))


def recipe_scheduler(recipe: Any, model: Any, total_steps: int) -> Callable | None:
    """The learning-rate schedule of a fit: the recipe's ``schedule`` (``cosine``: to 0 over ``total_steps``
    optimizer steps; ``constant`` or unset: ``model.scheduler``, null by default)."""
    schedule = str((recipe or {}).get("schedule") or "constant")
    if schedule == "cosine":
        return lambda opt: torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(1, int(total_steps)))
    if schedule != "constant":
        raise ValueError(f"recipe.schedule must be constant or cosine, found {schedule!r}")
    return instantiate(model.scheduler) if model.get("scheduler") else None


def _rows(part: FileRows | ArrayRows) -> int:
    if isinstance(part, ArrayRows):
        return len(part.y)
    return read_attrs(part.path)["n"] if part.rows is None else len(part.rows)


def _is_rank_zero() -> bool:
    return getattr(rank_zero_only, "rank", 0) == 0


class Job:
    """One train.py job; see the module docstring."""

    def __init__(self, cfg: DictConfig, run_dir: Path) -> None:
        self.cfg = cfg
        self.run_dir = Path(run_dir)
        self.seed = int(cfg.seed)
        self.rank_zero = _is_rank_zero()
        self.tracker: Tracker = Tracker("", "", enabled=False)
        self.real: ArrayDataset
        self.state: Path
        self.stages = Stages([])
        self._extra: dict[str, list[FileRows | ArrayRows]] = {}  # what a variant adds, made once per job
        self.params: dict[str, Any] = {}  # what the job found out and logged (split sizes, fitted values, ...)

    def log_params(self, params: dict[str, Any]) -> None:
        """Log parameters the job found out to its MLflow run, and keep them for the table it prints."""
        self.params.update(params)
        self.tracker.log_params(params)

    # ---- job life cycle ---------------------------------------------------------------------
    def run(self) -> dict[str, float]:
        cfg = self.cfg
        if cfg.get("threads"):
            torch.set_num_threads(int(cfg.threads))
        self.stages = Stages(self.stage_names())
        with self.stages("data"):
            real_path, data_hash, jhash = self.load_data()
        with self._state_lock():
            if not cfg.resume and self.rank_zero:
                shutil.rmtree(self.state, ignore_errors=True)
            self.state.mkdir(parents=True, exist_ok=True)
            job_file = self.state / "job.json"
            previous = json.loads(job_file.read_text()) if job_file.is_file() else {}
            if self.rank_zero:
                self.tracker = instantiate(cfg.logger) if cfg.get("logger") else self.tracker
            tags = {"preset": cfg.task_name, "seed": self.seed, "job_hash": jhash, "data_hash": data_hash,
                    "code_version": code_version(), "run_dir": self.run_dir, "data_path": real_path,
                    **({"world": world} if (world := group_choice("world")) else {})}  # make tables keeps worlds apart
            config = OmegaConf.to_container(cfg, resolve=True) if self.rank_zero else None
            data = DataRef.of(OmegaConf.to_container(cfg.data, resolve=True), real_path, data_hash)
            with tracked_run(self.tracker, run_name=data.run_name(cfg.task_name, self.seed), tags=tags, config=config,
                             run_id=previous.get("mlflow_run_id"), dataset=data) as run_id:
                if self.rank_zero:
                    atomic_write_text(job_file, json.dumps({"job_hash": jhash, "mlflow_run_id": run_id,
                                                            "run_dirs": [*previous.get("run_dirs", []), str(self.run_dir)]},
                                                           indent=1))
                results: dict[str, dict] = {}
                if cfg.job == "variants":
                    results = self.run_variants()
                elif cfg.job == "external_pretrain":
                    results = self.run_external_pretrain()
                elif "." in str(cfg.job):  # another job kind: a function (job: Job) -> {metric: number}
                    metrics = {k: float(v) for k, v in import_callable(str(cfg.job))(self).items()}
                else:
                    raise ValueError(f"job must be 'variants', 'external_pretrain' or a dotted function name, found {cfg.job!r}")
                if results:
                    metrics = {f"test/acc_{name}": r["acc"] for name, r in results.items()}
                if self.rank_zero:
                    self._write_outputs(results, metrics)
        return metrics

    def load_data(self) -> tuple[Path, str, str]:
        """Load the real dataset into ``real`` and locate the job's ``state`` folder (created by ``run``):
        (dataset path, data hash, job hash)."""
        real_path = instantiate(self.cfg.data.dataset).path()
        self.real = load_arrays(real_path)
        data_hash = file_hash(real_path)
        jhash = job_hash(self.cfg, data_hash)
        self.state = Path(self.cfg.state_dir) / jhash
        return real_path, data_hash, jhash

    def stage_names(self) -> list[str]:
        """The job's stages in order: the data, then (variants) what the variants add and each variant."""
        if self.cfg.job != "variants":
            return ["data", str(self.cfg.job)]
        names = variant_names(self.cfg.variants)
        adds = dict.fromkeys(VARIANTS[n][1] for n in names if VARIANTS[n][1] is not None)
        return ["data", *(ADDITION_STAGES[a] for a in adds), *names, "summary"]

    def _state_lock(self) -> contextlib.AbstractContextManager[None]:
        """One live job per state folder (two identical jobs would share checkpoints); DDP ranks > 0
        run inside rank 0's job."""
        return file_lock(self.state.parent / f"{self.state.name}.lock" if self.rank_zero else None,
                         busy_error=f"another job with the same config is running (state {self.state})")

    def _write_outputs(self, results: dict[str, dict], metrics: dict[str, float]) -> None:
        for name, r in results.items():
            cm_file = self.run_dir / "confusion" / f"{name}.json"
            atomic_write_text(cm_file, json.dumps({"classes": r["classes"], "matrix": r["confusion"]}))
            png = plot_confusion(np.asarray(r["confusion"]), r["classes"], self.run_dir / "figures" / f"confusion_{name}.png",
                                 title=f"{self.cfg.task_name} {name} seed {self.seed}")
            self.tracker.log_artifact(cm_file, "confusion")
            self.tracker.log_artifact(png, "figures")
        self.tracker.log_params({f"result.{name}.{k}": v for name, r in results.items() for k, v in r.items()
                                 if k.startswith("n_")})
        self.tracker.log_metrics(metrics)
        atomic_write_text(self.run_dir / "metrics.json", json.dumps(metrics, indent=1, sort_keys=True))
        if self.cfg.job == "variants" and results:
            with self.stages("summary"):
                self.tracker.log_artifact(self.plot_summary(results), "figures")

    def plot_summary(self, results: dict[str, dict]) -> Path:
        """``figures/summary.png``: accuracy by variant, and real vs synthetic spectrograms of the same
        pool recordings (three gestures) where the job synthesised any."""
        real, pairs = self.real, []
        synthetic = next((parts for parts in self._extra.values() if parts and isinstance(parts[0], FileRows)), None)
        if synthetic is not None:
            pool = np.load(self.state / "split.npz")["pool"]
            fake = load_arrays(synthetic[0].path)
            first = {}  # gesture -> index of its first pool row
            for i, c in enumerate(real.y[pool]):
                first.setdefault(int(c), i)
            for c in sorted(first)[:: max(1, len(first) // 3)][:3]:
                pairs.append((real.classes[c], real.x[pool[first[c]]], fake.x[first[c]]))
        return plot_summary({k: r["acc"] for k, r in results.items()}, self.run_dir / "figures" / "summary.png",
                            chance=1.0 / len(real.classes), pairs=pairs,
                            title=f"{self.cfg.task_name}, seed {self.seed}")

    # ---- building blocks --------------------------------------------------------------------
    def cached(self, name: str, compute: Callable[[], dict]) -> dict:
        """A variant's result, computed once per state folder (finished variants are not retrained)."""
        f = self.state / name / "result.json"
        if f.is_file():
            log.info("variant %s already finished (%s)", name, f)
            return json.loads(f.read_text())
        result = compute()
        if self.rank_zero:
            atomic_write_text(f, json.dumps(result))
            shutil.rmtree(self.state / name / "checkpoints", ignore_errors=True)  # resuming is over
        return result

    def _callbacks(self) -> list:
        return [instantiate(c) for c in (self.cfg.get("callbacks") or {}).values() if c is not None]

    def eval_device(self) -> str:
        """Where evaluation runs: the GPU when the trainer trains on one, else the CPU."""
        accel = str(self.cfg.trainer.get("accelerator", "cpu"))
        return "cuda" if accel in ("gpu", "cuda", "auto") and torch.cuda.is_available() else "cpu"

    def fit_classifier(self, name: str, parts: list[FileRows | ArrayRows], num_classes: int, *,
                       init: dict[str, torch.Tensor] | None = None, overrides: dict | None = None,
                       shares: list[float] | None = None) -> torch.nn.Module:
        """Train ``model.net`` on the training ``parts`` (through a DataModule) by the training ``recipe``, resumably;
        the same initial weights for every variant of a seed. ``shares``: each part's share of the batches (None: as
        many as its rows). ``overrides``: Trainer settings that win over the recipe's length."""
        cfg = self.cfg
        pl.seed_everything(self.seed, verbose=False)
        net = instantiate(cfg.model.net, num_classes=num_classes)
        if init is not None:
            missing, unexpected = net.load_state_dict(init, strict=False)
            if unexpected or any(not k.startswith("fc.") for k in missing):
                raise RuntimeError(f"pre-trained weights do not fit {name}: missing {missing}, unexpected {unexpected}")
        data = TrainingRowsDataModule(parts, batch_size=int(cfg.data.batch_size), seed=self.seed,
                                      num_workers=int(cfg.data.num_workers), shares=shares)
        recipe = cfg.get("recipe") or {}
        steps = recipe_steps(recipe, len(data), int(cfg.data.batch_size))
        overrides = {**({} if steps is None else {"max_steps": steps, "max_epochs": -1}), **(overrides or {})}
        module = ClassifierModule(net, num_classes, instantiate(cfg.model.optimizer),
                                  recipe_scheduler(recipe, cfg.model, overrides.get("max_steps", cfg.trainer.max_steps)),
                                  prefix=f"{name}/", augment=instantiate(recipe["augment"]) if recipe.get("augment") else None)
        ckpt_dir = self.state / name / "checkpoints"
        trainer = make_trainer(cfg.trainer, ckpt_dir=ckpt_dir, seed=self.seed, logger=TrackerLogger(self.tracker),
                               callbacks=self._callbacks(), overrides=overrides,
                               checkpoint_interval_s=float(cfg.get("checkpoint_interval_s", 0)))
        resumable_fit(trainer, module, data, ckpt_dir)
        if cfg.model.get("precise_bn", True):
            recompute_bn_stats(module.net, data.arrays()[0], device=self.eval_device())
        return module.net

    def train_and_test(self, name: str, parts: list[FileRows | ArrayRows], test_rows: np.ndarray, num_classes: int,
                       classes: list[str], *, test_y: np.ndarray | None = None, **kw) -> dict:
        net = self.fit_classifier(name, parts, num_classes, **kw)
        ty = self.real.y[test_rows] if test_y is None else test_y
        acc, cm = evaluate(net, self.real.x[test_rows], ty, num_classes, device=self.eval_device())
        log.info("%s: test accuracy %.4f on %d rows", name, acc, len(ty))
        return {"acc": acc, "confusion": cm.tolist(), "classes": classes, "n_train": sum(_rows(p) for p in parts),
                "n_test": int(len(ty)),
                "weights_hash": weights_hash(net)}

    # ---- few-shot and OOD variants ----------------------------------------------------------
    def split(self) -> Split:
        split = make_split(OmegaConf.to_container(self.cfg.split, resolve=True), self.real.y, self.real.meta, self.seed)
        if self.rank_zero:
            with atomic_path(self.state / "split.npz") as tmp:
                with open(tmp, "wb") as fh:
                    np.savez(fh, train=split.train, pool=split.pool, test=split.test)
            self.tracker.log_params({f"split_sizes.{k}": v for k, v in split.sizes().items()})
        if not len(split.test):
            raise ValueError(f"split {OmegaConf.to_container(self.cfg.split)} leaves no test rows")
        return split

    def run_variants(self) -> dict[str, dict]:
        split = self.split()
        real, n_classes = self.real, len(self.real.classes)
        names = variant_names(self.cfg.variants)
        pending = [n for n in names if not (self.state / n / "result.json").is_file()]
        for adds in dict.fromkeys(VARIANTS[n][1] for n in pending if VARIANTS[n][1] is not None):
            with self.stages(ADDITION_STAGES[adds]):  # made before training, so each stage is timed on its own
                self.extra_data(adds, split)
        results = {}
        for name in names:

            def compute(name: str = name) -> dict:
                rows, adds = VARIANTS[name]
                real_rows = {"train": split.train, "pool": split.pool, None: split.train[:0]}[rows]
                extra = self.extra_data(adds, split)
                parts = [FileRows(real.path, real_rows), *extra] if len(real_rows) else extra
                return {**self.train_and_test(name, parts, split.test, n_classes, real.classes),
                        "n_real": int(len(real_rows)), "n_extra": sum(_rows(p) for p in extra)}

            with self.stages(name):
                results[name] = self.cached(name, compute)
        return results

    def extra_data(self, adds: str | None, split: Split) -> list[FileRows | ArrayRows]:
        """What a variant adds to its real rows (``VARIANTS``): synthetic rows of the pool's skeletons
        (the provider fits what it needs on the real training rows only), CGAN samples, or nothing.
        Made once per job."""
        if adds is None:
            return []
        if adds not in self._extra:
            self._extra[adds] = self._make_extra(adds, split)
        return self._extra[adds]

    def _make_extra(self, adds: str, split: Split) -> list[FileRows | ArrayRows]:
        real = self.real
        if adds in ("model", "enhanced"):
            provider = instantiate(self.cfg.synth.provider)
            sims = self.synthesis_sims(split)
            parts = []
            for draw, sim in enumerate(sims):
                kw = {} if sim is None else {"sim": sim}  # None: the provider's own (the `sim` config)
                path = provider(real.path, split.pool, adds, fit_rows=split.train, seed=self.seed + 1000 * draw,
                                cache_dir=Path(self.cfg.synth.cache_dir), **kw)
                load_synthetic(path, real.y[split.pool], real.x.shape[1:])  # checks the provider's contract
                self.log_rwn_guard(path, draw)
                parts.append(FileRows(Path(path)))
            return parts
        if adds == "cgan":
            return [ArrayRows(*self.cgan_samples(split))]
        raise ValueError(f"unknown addition {adds!r}")

    def log_rwn_guard(self, path: str | Path, draw: int) -> None:
        """The held-out gain and shrink of a guarded RadarWeightNet (the file's ``rwn_guard``), as run metrics."""
        raw = read_attrs(path).get("rwn_guard")
        if raw is None:
            return
        g = json.loads(raw)
        tag = "" if draw == 0 else f"_draw{draw}"
        self.tracker.log_metrics({f"synth/rwn_heldout_gain{tag}": g["gain"], f"synth/rwn_heldout_gain_ci_low{tag}":
                                  g["gain_ci95"][0], f"synth/rwn_shrink{tag}": g["shrink"]})
        log.info("RadarWeightNet: held-out gain %+.3f [%+.3f, %+.3f] over %d rows in %d folds; best shrink %g "
                 "[%+.3f, %+.3f]; kept at s = %g (weights 1 + s (w - 1); 0 unless the best's CI clears 0)",
                 g["gain"], *g["gain_ci95"], g["rows"], g["folds"], g["shrink_best_ssim"],
                 *g["gain_chosen_ci95"], g["shrink"])

    def fitted_sim(self, split: Split) -> dict | None:
        """The ``sim`` settings fitted on the real training rows (``synth.fit_sim``; None: ``sim`` as
        configured), through the diagnosis's fitting path; cached in the job's state, logged to MLflow."""
        mode = str(self.cfg.synth.get("fit_sim", "none"))
        if mode not in ("none", "calibrate", "effects"):
            raise ValueError(f"synth.fit_sim must be none, calibrate or effects, found {mode!r}")
        if mode == "none":
            return None
        f = self.state / "fitted_sim.yaml"
        if f.is_file():
            return OmegaConf.to_container(OmegaConf.load(f), resolve=True)
        log.info("fitting the simulator (%s) on %d real training rows", mode, len(split.train))
        data = load_dataset(self.real.path).take(split.train)
        fit = self.cfg.synth.get("fit")
        fit_cfg = {"seed": self.seed, **(OmegaConf.to_container(fit, resolve=True) if fit else {})}
        try:
            diag, settings = fit_simulator(data, OmegaConf.to_container(self.cfg.sim, resolve=True), fit_cfg,
                                           cache_dir=Path(self.cfg.synth.cache_dir) / "fit", effects=mode == "effects")
        except TooFewRows as exc:  # raised before any fit: say which rows and how to get out of it
            raise TooFewRows(f"synth.fit_sim={mode} fits the simulator on the split's {len(split.train)} training "
                             f"rows (settings synth.fit.*): {exc}; use more rows per gesture (split.fraction, "
                             "split.per_class), or synth.fit_sim=none") from None
        if self.rank_zero:
            write_report(self.state / "fit_report.json", diag.report, n_doppler=data.chain.n_doppler,
                         n_columns=data.chain.n_columns)
            atomic_write_text(f, OmegaConf.to_yaml(settings))
            self.tracker.log_artifact(f, "synthesis")
            self.tracker.log_artifact(self.state / "fit_report.json", "synthesis")
            self.tracker.log_params({"synth.fitted.effects": ",".join(settings["effects"]) or "-",
                                     **{f"synth.fitted.{name}": settings.get(name, paper)
                                        for name, paper, _ in GENERIC_SETTINGS.values()}})
        return settings

    def synthesis_sims(self, split: Split) -> list[dict | None]:
        """One ``sim`` setting per synthetic sample of a pool row (``synth.samples_per_row``): the fitted
        simulator, with the nuisance parameters of ``synth.randomize`` drawn around their fitted values."""
        cfg = self.cfg.synth
        fitted = self.fitted_sim(split)
        k = int(cfg.get("samples_per_row", 1))
        spread = OmegaConf.to_container(cfg.randomize, resolve=True) if cfg.get("randomize") else {}
        if k < 1:
            raise ValueError(f"synth.samples_per_row must be >= 1, found {k}")
        if not spread:
            if k > 1:
                raise ValueError("synth.samples_per_row > 1 needs synth.randomize (identical draws add nothing)")
            return [fitted]
        base = fitted if fitted is not None else OmegaConf.to_container(self.cfg.sim, resolve=True)
        return [nuisance_draw(base, spread, np.random.default_rng([self.seed, j])) for j in range(k)]

    def cgan_samples(self, split: Split) -> tuple[np.ndarray, np.ndarray]:
        """CGAN trained on the real training rows; samples per class as many as the pool's rows
        of that class (the synthetic variants' count) or ``cgan.samples_per_class``."""
        f = self.state / "cgan_generator" / "samples.npz"
        if f.is_file():
            with np.load(f) as z:
                return z["x"], z["y"]
        cfg, real = self.cfg.cgan, self.real
        y = real.y[split.train]
        shape = (1, *real.x.shape[1:])
        n_classes = len(real.classes)
        pl.seed_everything(self.seed, verbose=False)
        gen = instantiate(cfg.generator, num_classes=n_classes, shape=shape)
        disc = instantiate(cfg.discriminator, num_classes=n_classes, shape=shape)
        module = CGANModule(gen, disc, lr=float(cfg.lr), betas=tuple(cfg.betas), real_label=float(cfg.real_label),
                            mismatch=bool(cfg.get("mismatch", True)))
        data = TrainingRowsDataModule([FileRows(real.path, split.train)], batch_size=int(cfg.batch_size), seed=self.seed,
                                      drop_last=len(y) > int(cfg.batch_size))
        ckpt_dir = self.state / "cgan_generator" / "checkpoints"
        trainer = make_trainer(self.cfg.trainer, ckpt_dir=ckpt_dir, seed=self.seed, logger=TrackerLogger(self.tracker),
                               callbacks=self._callbacks(), overrides={"max_steps": int(cfg.max_steps), "max_epochs": -1},
                               checkpoint_interval_s=float(self.cfg.get("checkpoint_interval_s", 0)))
        resumable_fit(trainer, module, data, ckpt_dir)
        pool_counts = np.bincount(real.y[split.pool], minlength=n_classes)
        per_class = cfg.get("samples_per_class")
        counts = {int(c): int(per_class if per_class is not None else pool_counts[c]) for c in np.unique(y)}
        gx, gy = sample_per_class(module.generator.cpu(), counts, seed=self.seed)
        if self.rank_zero:
            with atomic_path(f) as tmp:
                with open(tmp, "wb") as fh:
                    np.savez(fh, x=gx, y=gy)
            shutil.rmtree(ckpt_dir, ignore_errors=True)
        return gx, gy

    # ---- external pre-training --------------------------------------------------------------
    def finetune_split(self, fraction: float) -> Split:
        """The few-shot split of every class at ``fraction`` (the unstarred protocol); a class subset's
        fine-tune takes its classes' rows of it, so one seed's splits are nested across fractions and
        subsets, and the smallest fraction's rows, which fit the simulator, train every fine-tune."""
        return few_shot_split(self.real.y, float(fraction), seed=self.seed, test="remainder")

    def pretrained_backbone(self) -> dict[str, torch.Tensor]:
        f = self.state / "pretrain" / "backbone.pt"
        if f.is_file():
            return torch.load(f, map_location="cpu")
        source, source_cfg = external_source(self.cfg)
        provider = instantiate(self.cfg.synth.external_provider)
        # the closed loop: the radar's calibration and the Leap tracker's smoothing, fitted on the rows that
        # train every fine-tune (the smallest fraction's), carry over to the external skeletons
        fitted = self.fitted_sim(self.finetune_split(min(self.cfg.finetune.fractions)))
        extra = {} if fitted is None else {"sim": fitted}
        ext = load_arrays(provider(source_cfg, seed=self.seed, cache_dir=Path(self.cfg.synth.cache_dir), **extra))
        if ext.x.shape[1:] != self.real.x.shape[1:]:
            raise ValueError(f"external spectrograms {ext.x.shape[1:]} differ from the radar data's {self.real.x.shape[1:]}")
        net = self.fit_classifier("pretrain", [FileRows(ext.path)], len(ext.classes),
                                  overrides={"max_steps": int(self.cfg.pretrain.max_steps), "max_epochs": -1})
        state = backbone_state(net.cpu())
        if self.rank_zero:
            with atomic_path(f) as tmp:
                torch.save(state, tmp)
            shutil.rmtree(self.state / "pretrain" / "checkpoints", ignore_errors=True)
            self.tracker.log_params({"pretrain.source": source, "pretrain.n_rows": len(ext), "pretrain.n_classes": len(ext.classes)})
        return state

    def run_external_pretrain(self) -> dict[str, dict]:
        real, results = self.real, {}
        backbone = None
        splits = {float(f): self.finetune_split(f) for f in self.cfg.finetune.fractions}  # shared by the subsets
        for subset in self.cfg.finetune.class_subsets:
            names = list(real.classes) if subset is None else list(subset)
            unknown = sorted(set(names) - set(real.classes))
            if unknown:
                raise ValueError(f"finetune.class_subsets names {unknown}, not classes of {real.path} ({real.classes})")
            ids = [real.classes.index(n) for n in names]
            rows = np.flatnonzero(np.isin(real.y, ids))
            remap = np.full(len(real.classes), -1, dtype=np.int64)
            remap[ids] = np.arange(len(ids))
            for fraction in self.cfg.finetune.fractions:
                split = splits[float(fraction)]
                train, test = np.intersect1d(split.train, rows), np.intersect1d(split.test, rows)
                for init in ("scratch", "pretrained"):
                    name = f"{init}_{len(ids)}c_{float(fraction) * 100:g}pct"

                    def compute(init: str = init, train: np.ndarray = train, test: np.ndarray = test,
                                ytr: np.ndarray = remap[real.y[train]], yte: np.ndarray = remap[real.y[test]]) -> dict:
                        nonlocal backbone
                        if init == "pretrained" and backbone is None:
                            backbone = self.pretrained_backbone()
                        return self.train_and_test(name, [FileRows(real.path, train, ytr)], test, len(ids), names, test_y=yte,
                                                   init=backbone if init == "pretrained" else None)

                    with self.stages(name):
                        results[name] = self.cached(name, compute)
        return results


def external_source(cfg: DictConfig) -> tuple[str, Any]:
    """The external skeleton dataset Table III pre-trains on: DHG when ``data.dhg.root`` is set, else SFINGE3D."""
    dhg = cfg.data.get("dhg")
    if dhg is not None and dhg.get("root"):
        return "dhg", dhg
    return "sfinge3d", cfg.data.sfinge3d


def run(cfg: DictConfig, run_dir: str | Path | None = None) -> Path:
    """Run one job; returns its run directory (Hydra's output folder unless given)."""
    if run_dir is None:
        from hydra.core.hydra_config import HydraConfig

        run_dir = HydraConfig.get().runtime.output_dir
    run_dir = Path(run_dir).resolve()
    run_dir.mkdir(parents=True, exist_ok=True)
    job = Job(cfg, run_dir)
    try:
        metrics = job.run()
    except BaseException as exc:
        if _is_rank_zero():
            with contextlib.suppress(Exception):
                atomic_write_text(run_dir / "error.txt", f"{type(exc).__name__}: {exc}\n")
        raise
    if _is_rank_zero() and cfg.get("print_table", True):
        params = {k: str(v) for k, v in {**flatten(OmegaConf.to_container(cfg, resolve=True)), **job.params}.items()}
        if cfg.get("job") == "external_pretrain":  # the row's label, as the MLflow run has it
            params["pretrain.source"] = external_source(cfg)[0]
        print(job_table(params, metrics), flush=True)
        summary = run_dir / "figures" / "summary.png"
        if summary.is_file():
            print(f"summary figure: {summary}", flush=True)
    return run_dir
