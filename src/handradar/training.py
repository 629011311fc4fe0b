"""Resumable, reproducible Lightning fits: seeding, checkpoints, the MLflow logger.

A fit is a function of the seed alone, also across an interruption: the shuffling order of an
epoch depends only on (seed, epoch) (handradar.data.datamodule.EpochSeededSampler, which Lightning advances
through ``set_epoch``), and every training step reseeds torch's global generator from (seed, step, rank)
(:class:`StepSeed`, so dropout masks and GAN noise do not depend on the history of the
process). A fit resumes from ``<ckpt_dir>/last.ckpt`` (:class:`EpochStartCheckpoint`, rewritten as
each epoch starts), so a job killed during epoch k repeats only epoch k and ends with the same weights.
"""

from __future__ import annotations

import logging
import time
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import lightning.pytorch as pl
import torch
from hydra.utils import instantiate
from lightning.pytorch.callbacks import Callback
from lightning.pytorch.loggers.logger import Logger
from lightning.pytorch.utilities import rank_zero_only
from omegaconf import DictConfig, OmegaConf

from handradar.runs.mlflow import Tracker
from handradar.runs.progress import clock_text

log = logging.getLogger(__name__)

# Lightning 2.x calls a torch pytree API that torch 2.14 deprecates, once per batch: a wall of
# identical lines in every job's log that says nothing about the job (tests silence it likewise).
warnings.filterwarnings("ignore", message=r"`isinstance\(treespec, LeafSpec\)` is deprecated", category=FutureWarning)


class StepSeed(Callback):
    """Reseed torch's global generator before every training batch from (seed, step, rank)."""

    def __init__(self, seed: int) -> None:
        self.seed = int(seed)

    def on_train_batch_start(self, trainer: pl.Trainer, pl_module: pl.LightningModule, batch: Any, batch_idx: int) -> None:
        torch.manual_seed((self.seed * 1_000_003 + trainer.global_step) * 64 + trainer.global_rank)


class EpochStartCheckpoint(Callback):
    """Write ``<dirpath>/last.ckpt`` at the start of every epoch after the first.

    Not ModelCheckpoint's end-of-epoch file: Lightning restores such a file as an unfinished
    epoch and replays one extra optimizer step (Lightning issue #19403), so a resumed fit would
    not match an uninterrupted one. At the start of epoch k, epochs 0..k-1 are complete in the
    loop state, and a restore continues exactly with epoch k.

    interval_s: skip epochs that start less than this long after the previous save (tiny datasets
    have epochs of a few steps, and a ResNet checkpoint with its optimizer state is ~130 MB). When a
    checkpoint is taken does not change the training, only how much a resume repeats.
    """

    def __init__(self, dirpath: str | Path, interval_s: float = 0.0) -> None:
        self.path = Path(dirpath) / "last.ckpt"
        self.interval_s = float(interval_s)
        self._last = time.monotonic()

    def on_train_batch_start(self, trainer: pl.Trainer, pl_module: pl.LightningModule, batch: Any, batch_idx: int) -> None:
        if batch_idx or trainer.current_epoch == 0 or trainer.fast_dev_run:
            return
        due = time.monotonic() - self._last >= self.interval_s
        if trainer.world_size > 1:  # every rank must agree: saving is collective
            due = bool(trainer.strategy.broadcast(due, src=0))
        if due:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            trainer.save_checkpoint(self.path)  # rank 0 writes, atomically
            self._last = time.monotonic()


class StepProgress(Callback):
    """Log ``<name>: step k/N (elapsed m:ss, about m:ss left)`` at most every ``interval_s`` seconds: the
    progress of a fit whose progress bar is off (sweeps whose logs go to files), which would otherwise be
    silent for as long as it trains."""

    def __init__(self, name: str, interval_s: float = 60.0, clock: Any = time.monotonic) -> None:
        self.name, self.interval_s, self.clock = name, float(interval_s), clock

    def on_train_start(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        self._t0 = self._last = self.clock()
        self._step0 = trainer.global_step  # a resumed fit: its rate counts only the steps taken now

    def on_train_batch_end(self, trainer: pl.Trainer, pl_module: pl.LightningModule, outputs: Any, batch: Any,
                           batch_idx: int) -> None:
        now, step, total = self.clock(), trainer.global_step, trainer.max_steps
        if now - self._last < self.interval_s or trainer.global_rank:
            return
        self._last = now
        elapsed, done = now - self._t0, step - self._step0
        left = f", about {clock_text(elapsed / done * (total - step))} left" if total > 0 and done > 0 else ""
        log.info("%s: step %d%s (elapsed %s%s)", self.name, step, f"/{total}" if total > 0 else "", clock_text(elapsed), left)


def make_trainer(trainer_cfg: DictConfig | Mapping, *, ckpt_dir: Path, seed: int, logger: Any = False,
                 callbacks: Sequence[Callback] = (), overrides: Mapping[str, Any] | None = None,
                 checkpoint_interval_s: float = 0.0) -> pl.Trainer:
    """A Trainer from the ``trainer`` config plus resumable checkpointing into ``ckpt_dir``; without a
    progress bar, the fit logs its steps (:class:`StepProgress`, named after ``ckpt_dir``'s parent)."""
    cfg = OmegaConf.merge(trainer_cfg, dict(overrides or {}))
    if not cfg.get("enable_progress_bar", True):
        callbacks = [*callbacks, StepProgress(Path(ckpt_dir).parent.name)]
    return instantiate(cfg, callbacks=[*callbacks, StepSeed(seed), EpochStartCheckpoint(ckpt_dir, checkpoint_interval_s)],
                       logger=logger,
                       default_root_dir=str(ckpt_dir), enable_checkpointing=False)


def resumable_fit(trainer: pl.Trainer, module: pl.LightningModule, data: pl.LightningDataModule | None,
                  ckpt_dir: Path) -> None:
    """``trainer.fit`` on the DataModule ``data`` (None: the module's own) that continues from
    ``ckpt_dir/last.ckpt`` when an earlier fit was interrupted."""
    last = Path(ckpt_dir) / "last.ckpt"
    if last.is_file():
        log.info("resuming %s from %s", type(module).__name__, last)
    trainer.fit(module, datamodule=data, ckpt_path=str(last) if last.is_file() else None)


class TrackerLogger(Logger):
    """Lightning logger that writes epoch metrics into the job's MLflow run under a prefix.

    The MLflow step of an epoch-level metric is its epoch (Lightning's own step counter for epoch
    metrics shifts by one after a resume)."""

    def __init__(self, tracker: Tracker, prefix: str = "") -> None:
        super().__init__()
        self.tracker = tracker
        self.prefix = prefix

    @property
    def name(self) -> str:
        return "mlflow"

    @property
    def version(self) -> str:
        return self.tracker.run_id or "offline"

    @rank_zero_only
    def log_hyperparams(self, params: Any, *args: Any, **kwargs: Any) -> None:
        """The job logs its whole config once; per-fit hyperparameters add nothing."""

    @rank_zero_only
    def log_metrics(self, metrics: Mapping[str, float], step: int | None = None) -> None:
        if "epoch" in metrics:
            step = int(metrics["epoch"])
        self.tracker.log_metrics({f"{self.prefix}{k}": v for k, v in metrics.items() if k != "epoch"}, step)
