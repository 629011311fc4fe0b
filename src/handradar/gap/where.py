"""Where the gap lies: residual profiles over Doppler and time, and the gap by factor.

Residual = measured - simulated spectrogram (both in [0, 1]); positive where the measurement has
energy the simulator lacks, negative where the simulator puts energy the measurement lacks.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np


def residual_profiles(measured: np.ndarray, simulated: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signed mean residual over Doppler rows (64,) and over time columns (32,) of (N, 64, 32) stacks."""
    r = np.asarray(measured, dtype=np.float64) - np.asarray(simulated, dtype=np.float64)
    return r.mean(axis=(0, 2)), r.mean(axis=(0, 1))


def _level_name(v: object) -> str:
    if isinstance(v, (bool, np.bool_)):
        return "true" if v else "false"
    if isinstance(v, (float, np.floating)) and float(v).is_integer():
        return str(int(v))
    return str(v)


def by_factor(ssim: np.ndarray, meta: Mapping[str, np.ndarray], factors: tuple[str, ...]) -> dict[str, dict]:
    """Mean SSIM and count per level of each factor: {factor: {level: {"ssim", "n"}}}.

    Factors the data lack give an empty object (the report keeps every key).
    """
    ssim = np.asarray(ssim, dtype=np.float64)
    out: dict[str, dict] = {}
    for f in factors:
        levels: dict[str, dict] = {}
        if f in meta:
            values = np.asarray(meta[f])
            for level in sorted(set(values.tolist()), key=lambda v: (str(type(v)), v)):
                sel = values == level
                levels[_level_name(level)] = {"ssim": float(ssim[sel].mean()), "n": int(sel.sum())}
        out[f] = levels
    return out


def signature_correlation(residual: np.ndarray, explained: np.ndarray) -> float:
    """Pearson correlation of a residual profile with the change an effect makes (explained part)."""
    a = np.asarray(residual, dtype=np.float64).ravel()
    b = np.asarray(explained, dtype=np.float64).ravel()
    if a.std() == 0 or b.std() == 0:
        return 0.0
    return float(np.corrcoef(a, b)[0, 1])
