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

Statistics of one (doppler, columns) image in [0, 1], zero Doppler at row n // 2 (:data:`STATISTICS`: level, floor,
Doppler centroid and spread, zero band, motion's columns, reach and bursts), each (..., doppler, columns) -> (...):
the unpaired gap report's (handradar.gap.unpaired) and the unpaired fit's ``rows`` objective
(handradar.synthesis.measured); ``cohen_d`` ranks them.
"""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from scipy.signal import find_peaks
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


ZERO_BAND = 2  # rows either side of zero Doppler counted as the zero-Doppler band
BURST_PROMINENCE = 0.3  # a burst's peak stands out of the off-band energy by this share of the image's largest
BURST_APART = 5  # columns at least between two bursts' peaks


def _weights(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Doppler row offsets from zero (rows - n // 2) and each image's Doppler profile (summed over time)."""
    n = x.shape[-2]
    rows = np.arange(n) - n // 2
    profile = x.sum(axis=-1)
    return rows, profile / np.maximum(profile.sum(axis=-1, keepdims=True), 1e-12)


def doppler_centroid(x: np.ndarray) -> np.ndarray:
    rows, p = _weights(x)
    return (p * rows).sum(axis=-1)


def doppler_spread(x: np.ndarray) -> np.ndarray:
    rows, p = _weights(x)
    centre = (p * rows).sum(axis=-1, keepdims=True)
    return np.sqrt((p * (rows - centre) ** 2).sum(axis=-1))


def zero_band_share(x: np.ndarray) -> np.ndarray:
    rows, p = _weights(x)
    return p[..., np.abs(rows) <= ZERO_BAND].sum(axis=-1)


def _off_band(x: np.ndarray) -> np.ndarray:
    """Each column's energy off the zero band (..., columns)."""
    n = x.shape[-2]
    return np.delete(x, np.arange(n // 2 - ZERO_BAND, n // 2 + ZERO_BAND + 1), axis=-2).sum(axis=-2)


def moving_share(x: np.ndarray) -> np.ndarray:
    """Share of columns whose energy off the zero band exceeds half of the image's largest such column."""
    off = _off_band(x)
    return (off > 0.5 * off.max(axis=-1, keepdims=True)).mean(axis=-1)


def _bursts(x: np.ndarray) -> list[np.ndarray]:
    """Per image, the columns where its bursts of motion peak: the maxima of the off-band energy (the column's
    background, its median over the image, taken off; smoothed over 3 columns) that stand out of it by at least
    ``BURST_PROMINENCE`` of its largest, at least ``BURST_APART`` columns apart."""
    off = _off_band(x.reshape(-1, *x.shape[-2:]))
    off = np.clip(off - np.median(off, axis=-1, keepdims=True), 0.0, None)
    kernel = np.ones(3) / 3
    out = []
    for e in off:
        e = np.convolve(e, kernel, mode="same")
        peaks, _ = find_peaks(e, prominence=BURST_PROMINENCE * max(e.max(), 1e-12), distance=BURST_APART)
        out.append(peaks)
    return out


def burst_count(x: np.ndarray) -> np.ndarray:
    """How many bursts of motion each image holds (:func:`_bursts`): a tap 1, a double-click 2, a circle its turns."""
    return np.array([len(p) for p in _bursts(x)], dtype=np.float64).reshape(x.shape[:-2])


def burst_span(x: np.ndarray) -> np.ndarray:
    """Columns from each image's first burst peak to its last (0: one burst or none): how far apart repetitions lie."""
    return np.array([p[-1] - p[0] if len(p) else 0 for p in _bursts(x)], dtype=np.float64).reshape(x.shape[:-2])


def doppler_reach(x: np.ndarray) -> np.ndarray:
    """Rows from zero Doppler out to the farthest row whose brightest pixel stands half-way from the image's median
    (its background) to its peak: how fast the fastest part of the motion gets, in Doppler rows."""
    n = x.shape[-2]
    rows = np.abs(np.arange(n) - n // 2)
    level = np.median(x, axis=(-2, -1), keepdims=True)[..., 0]
    brightest = x.max(axis=-1)
    lit = brightest > level + 0.5 * (brightest.max(axis=-1, keepdims=True) - level)
    return np.where(lit, rows, 0).max(axis=-1).astype(np.float64)


STATISTICS: dict[str, tuple[Callable[[np.ndarray], np.ndarray], str]] = {
    "mean_level": (lambda x: x.mean(axis=(-2, -1)), "mean value of the image (0: floor, 1: peak)"),
    "floor_share": (lambda x: (x <= 1e-3).mean(axis=(-2, -1)), "share of pixels at the dB floor"),
    "doppler_centroid": (doppler_centroid, "energy-weighted Doppler row offset from zero (+: approaching)"),
    "doppler_spread": (doppler_spread, "energy-weighted standard deviation of the Doppler row"),
    "zero_band_share": (zero_band_share, f"share of the energy within {ZERO_BAND} rows of zero Doppler"),
    "moving_share": (moving_share, "share of the columns holding motion off the zero band"),
    "doppler_reach": (doppler_reach, "rows from zero Doppler that the motion reaches at half the image's peak"),
    "burst_count": (burst_count, "bursts of motion off the zero band (a double-click 2, a circle its turns)"),
    "burst_span": (burst_span, "columns from the first burst's peak to the last's"),
}
MOTION_STATISTICS = ("doppler_reach", "burst_count", "burst_span")  # the report's table of the motion's own terms


def cohen_d(a: np.ndarray, b: np.ndarray) -> float:
    """(mean b - mean a) / pooled standard deviation; 0 where both are constant and equal."""
    pooled = float(np.sqrt(0.5 * (a.var(ddof=1) + b.var(ddof=1)))) if len(a) > 1 and len(b) > 1 else 0.0
    diff = float(b.mean() - a.mean())
    return diff / pooled if pooled > 0 else (0.0 if diff == 0 else float(np.sign(diff)) * np.inf)
