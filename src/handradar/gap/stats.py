"""Statistics of the sim-to-real gap: per-example SSIM/MSE, gap closed, paired bootstrap.

gap = 1 - SSIM(measured, simulated), averaged over examples. An effect's ``gap_closed`` is
(gap_before - gap_after) / gap_before on the evaluation split. Confidence intervals come from a
paired bootstrap over evaluation examples (the same resampled examples for before and after), so
the spread of per-example difficulty cancels out of the comparison.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torchmetrics.functional.image import structural_similarity_index_measure


def per_example_ssim(measured: torch.Tensor, simulated: torch.Tensor) -> np.ndarray:
    """SSIM of each (64, 32) pair in [0, 1] (data_range 1.0): shape (N,)."""
    m = torch.as_tensor(measured, dtype=torch.float32).reshape(-1, 1, *measured.shape[-2:])
    s = torch.as_tensor(simulated, dtype=torch.float32).reshape(-1, 1, *simulated.shape[-2:])
    out = structural_similarity_index_measure(s, m, data_range=1.0, reduction="none")
    return out.detach().cpu().numpy().astype(np.float64)


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
