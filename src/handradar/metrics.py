"""Metrics of spectrogram agreement, one functional module: SSIM, MSE, gap closed, paired bootstrap.

Spectrograms are in [0, 1] (handradar.radar.chain.power_to_unit), hence SSIM with
``data_range=1.0`` (torchmetrics' functional implementation; Gaussian 11 x 11 window, sigma 1.5,
K1 0.01, K2 0.03). The same definitions serve the synthesis loss (Tang et al.: 1 - SSIM), Table I
and the gap diagnosis.

gap = 1 - SSIM(measured, simulated), averaged over examples. An effect's ``gap_closed`` is
(gap_before - gap_after) / gap_before on the evaluation split.

Confidence intervals come from a paired bootstrap over evaluation examples (the same resampled examples for before and after), so
the spread of per-example difficulty cancels out of the comparison.

Public API:

    ssim(pred, target, reduction="elementwise_mean" | "none") -> scalar or (B,)   (differentiable)
    ssim_loss(pred, target) -> 1 - mean SSIM;  fast_ssim_loss: same value and gradient, faster CPU backward
    per_example_ssim(measured, simulated) -> (N,) numpy;  per_example_mse(measured, simulated) -> (N,)
    gap_closed(ssim_before, ssim_after) -> float
    bootstrap_gap_closed(...) -> Bootstrap;  bootstrap_difference(...) -> (difference, 95 % CI)
"""

from __future__ import annotations

import contextlib
import warnings
from dataclasses import dataclass

import numpy as np
import torch
from torchmetrics.functional.image import structural_similarity_index_measure

DATA_RANGE = 1.0


# ---- differentiable SSIM (training losses) ---------------------------------------------------
def _four_d(x: torch.Tensor) -> torch.Tensor:
    if x.dim() == 3:
        return x[:, None]
    if x.dim() == 4:
        return x
    raise ValueError(f"spectrograms must be (B, H, W) or (B, 1, H, W), found {tuple(x.shape)}")


def ssim(pred: torch.Tensor, target: torch.Tensor, reduction: str = "elementwise_mean") -> torch.Tensor:
    """SSIM of spectrogram pairs in [0, 1]; ``reduction="none"`` gives one value per example."""
    pred, target = _four_d(pred), _four_d(target)
    target = target.to(pred.dtype)
    return structural_similarity_index_measure(pred, target, data_range=DATA_RANGE,
                                               reduction=None if reduction == "none" else reduction)


def ssim_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """1 - mean SSIM: the synthesis loss of Tang et al."""
    return 1.0 - ssim(pred, target)


class _SsimWithoutOneDNN(torch.autograd.Function):
    """SSIM whose forward and backward run with oneDNN convolutions off: torchmetrics' single-channel
    11 x 11 Gaussian convolution is ~3.5x faster backward on a CPU through ATen's own kernel."""

    @staticmethod
    def forward(ctx, pred, target, reduction):
        with torch.enable_grad(), _onednn_off():
            p = pred.detach().requires_grad_(True)
            value = ssim(p, target, reduction)
        ctx.p, ctx.value = p, value
        return value.detach()

    @staticmethod
    def backward(ctx, grad):
        with _onednn_off():
            (g,) = torch.autograd.grad(ctx.value, ctx.p, grad, retain_graph=True)
        return g, None, None


def _onednn_off():
    @contextlib.contextmanager
    def cm():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the flags context warns about TF32 on Intel GPUs
            with torch.backends.mkldnn.flags(enabled=False):
                yield

    return cm()


def fast_ssim_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """:func:`ssim_loss` with a faster CPU backward (same values and gradients; no double backward)."""
    if pred.device.type != "cpu" or not pred.requires_grad:
        return ssim_loss(pred, target)
    return 1.0 - _SsimWithoutOneDNN.apply(pred, target, "elementwise_mean")


# ---- per-example scores and the gap statistics -------------------------------------------------
def per_example_ssim(measured: torch.Tensor, simulated: torch.Tensor, chunk: int = 1024) -> np.ndarray:
    """SSIM of each (H, W) pair in [0, 1]: shape (N,) float64, no gradient; ``chunk`` pairs at a time (the SSIM's
    intermediate maps take ~20x the pairs' memory)."""
    m = torch.as_tensor(measured, dtype=torch.float32).reshape(-1, 1, *measured.shape[-2:])
    s = torch.as_tensor(simulated, dtype=torch.float32).reshape(-1, 1, *simulated.shape[-2:])
    parts = [ssim(s[i:i + chunk], m[i:i + chunk], reduction="none").detach().cpu() for i in range(0, len(m), chunk)]
    return torch.cat(parts).numpy().astype(np.float64) if parts else np.zeros(0)


def per_example_mse(measured: torch.Tensor, simulated: torch.Tensor) -> np.ndarray:
    d = torch.as_tensor(measured, dtype=torch.float32) - torch.as_tensor(simulated, dtype=torch.float32)
    return d.pow(2).flatten(1).mean(1).detach().cpu().numpy().astype(np.float64)


def gap_closed(ssim_before: np.ndarray, ssim_after: np.ndarray) -> float:
    gap_before = 1.0 - float(np.mean(ssim_before))
    if gap_before <= 0:
        return 0.0
    return (gap_before - (1.0 - float(np.mean(ssim_after)))) / gap_before


@dataclass(frozen=True)
class Bootstrap:
    """Paired bootstrap of gap_closed: point estimate, 95 % interval, and the replicates."""

    estimate: float
    ci95: tuple[float, float]
    replicates: np.ndarray

    @property
    def significant(self) -> bool:
        return self.ci95[0] > 0


def bootstrap_gap_closed(ssim_before: np.ndarray, ssim_after: np.ndarray, *, n_boot: int = 2000,
                         seed: int = 0) -> Bootstrap:
    """Paired bootstrap (resample evaluation examples) of gap_closed with a 95 % percentile interval."""
    before = np.asarray(ssim_before, dtype=np.float64)
    after = np.asarray(ssim_after, dtype=np.float64)
    if before.shape != after.shape or before.ndim != 1 or before.size < 2:
        raise ValueError(f"need two equal-length 1-D arrays of >= 2 examples, found {before.shape} and {after.shape}")
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, before.size, size=(n_boot, before.size))
    gb = 1.0 - before[idx].mean(axis=1)
    ga = 1.0 - after[idx].mean(axis=1)
    reps = np.where(gb > 0, (gb - ga) / np.where(gb > 0, gb, 1.0), 0.0)
    lo, hi = np.percentile(reps, [2.5, 97.5])
    return Bootstrap(gap_closed(before, after), (float(lo), float(hi)), reps)


def bootstrap_difference(ssim_before: np.ndarray, ssim_a: np.ndarray, ssim_b: np.ndarray, *,
                         n_boot: int = 2000, seed: int = 0) -> tuple[float, tuple[float, float]]:
    """Paired bootstrap of gap_closed(a) - gap_closed(b): is candidate a clearly ahead of b?"""
    before, a, b = (np.asarray(x, dtype=np.float64) for x in (ssim_before, ssim_a, ssim_b))
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, before.size, size=(n_boot, before.size))
    gb = 1.0 - before[idx].mean(axis=1)
    safe = np.where(gb > 0, gb, 1.0)
    diff = ((1.0 - b[idx].mean(axis=1)) - (1.0 - a[idx].mean(axis=1))) / safe
    lo, hi = np.percentile(diff, [2.5, 97.5])
    return gap_closed(before, a) - gap_closed(before, b), (float(lo), float(hi))
