"""Gesture classification: a thin LightningModule around a backbone, and plain evaluation."""

from __future__ import annotations

from collections.abc import Callable, Iterable

import lightning.pytorch as pl
import numpy as np
import torch
from torch import nn
from torch.nn import functional as F
from torchmetrics.classification import MulticlassAccuracy
from torchmetrics.functional.classification import multiclass_confusion_matrix


class ClassifierModule(pl.LightningModule):
    """Cross-entropy training of ``net``; logs ``<prefix>train/loss`` and ``<prefix>train/acc`` per epoch.

    optimizer: a factory ``params -> torch.optim.Optimizer`` (a Hydra ``_partial_``).
    scheduler: optional factory ``optimizer -> LR scheduler`` stepped once per optimizer step.
    augment: optional label-keeping transform of every training batch (handradar.models.augment.SpectrogramAugment).
    """

    def __init__(self, net: nn.Module, num_classes: int, optimizer: Callable[[Iterable], torch.optim.Optimizer],
                 scheduler: Callable | None = None, prefix: str = "", augment: nn.Module | None = None) -> None:
        super().__init__()
        self.net = net
        self.optimizer_factory = optimizer
        self.scheduler_factory = scheduler
        self.prefix = prefix
        self.augment = augment
        self.train_acc = MulticlassAccuracy(num_classes, average="micro")

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)

    def training_step(self, batch: tuple[torch.Tensor, torch.Tensor], batch_idx: int) -> torch.Tensor:
        x, y = batch
        if self.augment is not None:
            x = self.augment(x)
        logits = self.net(x)
        loss = F.cross_entropy(logits, y)
        self.train_acc(logits, y)
        self.log(f"{self.prefix}train/loss", loss, on_step=False, on_epoch=True, sync_dist=True, batch_size=len(y))
        self.log(f"{self.prefix}train/acc", self.train_acc, on_step=False, on_epoch=True, batch_size=len(y))
        return loss

    def configure_optimizers(self):
        opt = self.optimizer_factory(self.net.parameters())
        if self.scheduler_factory is None:
            return opt
        return {"optimizer": opt, "lr_scheduler": {"scheduler": self.scheduler_factory(opt), "interval": "step"}}


@torch.no_grad()
def recompute_bn_stats(net: nn.Module, x: np.ndarray, *, batch_size: int = 256,
                       device: str | torch.device | None = None) -> None:
    """Replace BatchNorm running statistics by the exact statistics of the final weights on ``x``
    (precise BN). After short trainings on few examples the running averages still lag the
    fast-moving weights, and an eval-mode network can collapse onto one class even though its
    training-mode predictions are right."""
    if not any(isinstance(m, nn.modules.batchnorm._BatchNorm) for m in net.modules()):
        return
    device = torch.device(device) if device is not None else next(net.parameters()).device
    xt = torch.as_tensor(np.asarray(x, dtype=np.float32))[:, None]
    loader = [xt[lo:lo + batch_size].to(device) for lo in range(0, len(xt), batch_size)]
    was_training = net.training
    torch.optim.swa_utils.update_bn(loader, net.to(device))
    net.train(was_training)


@torch.no_grad()
def predict(net: nn.Module, x: np.ndarray, *, batch_size: int = 256, device: str | torch.device | None = None) -> np.ndarray:
    """Predicted class of each spectrogram (N, 64, 32) with the network in eval mode."""
    device = torch.device(device) if device is not None else next(net.parameters()).device
    was_training = net.training
    net.eval().to(device)
    out = []
    for lo in range(0, len(x), batch_size):
        xb = torch.as_tensor(np.asarray(x[lo:lo + batch_size], dtype=np.float32))[:, None].to(device)
        out.append(net(xb).argmax(1).cpu())
    net.train(was_training)
    return torch.cat(out).numpy() if out else np.zeros(0, dtype=np.int64)


def evaluate(net: nn.Module, x: np.ndarray, y: np.ndarray, num_classes: int, **kw) -> tuple[float, np.ndarray]:
    """Accuracy in [0, 1] and the confusion matrix (rows: true class, columns: predicted)."""
    if len(y) == 0:
        raise ValueError("evaluation set is empty")
    pred = predict(net, x, **kw)
    cm = multiclass_confusion_matrix(torch.as_tensor(pred), torch.as_tensor(np.asarray(y)), num_classes)
    return float((pred == np.asarray(y)).mean()), cm.numpy().astype(np.int64)
