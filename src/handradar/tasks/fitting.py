"""Resumable, reproducible Lightning fits: loaders, seeding, checkpoints.

A fit is a function of the seed alone, also across an interruption: the shuffling order of an
epoch depends only on (seed, epoch) (:class:`EpochSeededSampler`, which Lightning advances through
``set_epoch``), and every training step reseeds torch's global generator from (seed, step, rank)
(:class:`StepSeed`, so dropout masks and GAN noise do not depend on the history of the
process). A fit resumes from ``<ckpt_dir>/last.ckpt`` (ModelCheckpoint ``save_last`` at every epoch
end), so a job killed during epoch k repeats only epoch k and ends with the same weights.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import lightning.pytorch as pl
import numpy as np
import torch
from hydra.utils import instantiate
from lightning.pytorch.callbacks import Callback, ModelCheckpoint
from omegaconf import DictConfig, OmegaConf
from torch.utils.data import DataLoader, Sampler, TensorDataset

log = logging.getLogger(__name__)


class EpochSeededSampler(Sampler[int]):
    """A permutation of ``range(n)`` that depends only on (seed, epoch)."""

    def __init__(self, n: int, seed: int) -> None:
        self.n, self.seed, self.epoch = n, int(seed), 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return self.n

    def __iter__(self) -> Iterator[int]:
        g = torch.Generator().manual_seed(self.seed * 1_000_003 + self.epoch)
        return iter(torch.randperm(self.n, generator=g).tolist())


class StepSeed(Callback):
    """Reseed torch's global generator before every training batch from (seed, step, rank)."""

    def __init__(self, seed: int) -> None:
        self.seed = int(seed)

    def on_train_batch_start(self, trainer: pl.Trainer, pl_module: pl.LightningModule, batch: Any, batch_idx: int) -> None:
        torch.manual_seed((self.seed * 1_000_003 + trainer.global_step) * 64 + trainer.global_rank)


def tensor_loader(x: np.ndarray, y: np.ndarray, *, batch_size: int, seed: int, shuffle: bool = True,
                  num_workers: int = 0, drop_last: bool = False) -> DataLoader:
    """Spectrograms (N, 64, 32) and labels (N,) as a loader of ((B, 1, 64, 32), (B,)) batches."""
    ds = TensorDataset(torch.as_tensor(np.asarray(x, dtype=np.float32))[:, None], torch.as_tensor(np.asarray(y, dtype=np.int64)))
    sampler = EpochSeededSampler(len(ds), seed) if shuffle else None
    return DataLoader(ds, batch_size=min(batch_size, len(ds)), sampler=sampler, num_workers=num_workers,
                      drop_last=drop_last, persistent_workers=num_workers > 0)


def make_trainer(trainer_cfg: DictConfig | Mapping, *, ckpt_dir: Path, seed: int, logger: Any = False,
                 callbacks: Sequence[Callback] = (), overrides: Mapping[str, Any] | None = None) -> pl.Trainer:
    """A Trainer from the ``trainer`` config plus checkpointing into ``ckpt_dir``."""
    ckpt = ModelCheckpoint(dirpath=ckpt_dir, save_last=True, save_top_k=0, every_n_epochs=1,
                           save_on_train_epoch_end=True, enable_version_counter=False)
    cfg = OmegaConf.merge(trainer_cfg, dict(overrides or {}))
    return instantiate(cfg, callbacks=[*callbacks, StepSeed(seed), ckpt], logger=logger, default_root_dir=str(ckpt_dir))


def resumable_fit(trainer: pl.Trainer, module: pl.LightningModule, loader: DataLoader, ckpt_dir: Path) -> None:
    """``trainer.fit`` that continues from ``ckpt_dir/last.ckpt`` when an earlier fit was interrupted."""
    last = Path(ckpt_dir) / "last.ckpt"
    if last.is_file():
        log.info("resuming %s from %s", type(module).__name__, last)
    trainer.fit(module, train_dataloaders=loader, ckpt_path=str(last) if last.is_file() else None)
