"""Where the gap lies: residual profiles over Doppler and time, and the gap by factor.

Residual = measured - simulated spectrogram (both in [0, 1]); positive where the measurement has
energy the simulator lacks, negative where the simulator puts energy the measurement lacks.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch

from handradar.hand.skeleton import BONE_NAMES, N_BONES
from handradar.radar.chain import ChainConfig, profile_power
from handradar.sim.scatterers import N_SLOTS


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


def slot_power(slot_profiles: torch.Tensor, chain: ChainConfig) -> torch.Tensor:
    """Per-slot STFT power (B, slots, doppler, columns) of slot profiles (B, slots, F, L, Ch, bins),
    through the chain's clutter removal and STFT (the steps before the dB scale)."""
    return profile_power(slot_profiles, chain)


class BoneResiduals:
    """Which reflection points carry excess or missing energy (``where.reflection_points``).

    Measure, per bone: the signed mean residual (measured - simulated, spectrogram units) over the
    pixels where the simulated spectrogram is above its floor, each pixel weighted by the bone's
    share of the simulated power there (its slot's STFT power over the sum of all slots' powers,
    from the per-bone decomposition Simulator.slot_profiles). Positive: the measurement holds more
    energy where this bone reflects than the simulator gives it (missing energy); negative: the
    simulator gives it too much (excess). Both hands of a bone are pooled; the unweighted slot
    (palm, forearm points of the simulator) appears as ``unweighted`` when it holds energy.
    """

    def __init__(self) -> None:
        self.num = np.zeros(N_SLOTS + 1)
        self.den = np.zeros(N_SLOTS + 1)

    def add(self, power: torch.Tensor, residual: np.ndarray, simulated: np.ndarray) -> None:
        """power (B, 39, doppler, columns) per slot; residual, simulated (B, doppler, columns)."""
        p = power.double()
        share = p / p.sum(1, keepdim=True).clamp_min(1e-300)
        shown = torch.as_tensor(np.asarray(simulated) > 0, dtype=torch.float64)[:, None]
        r = torch.as_tensor(np.asarray(residual, dtype=np.float64))[:, None]
        self.num += (share * shown * r).sum(dim=(0, 2, 3)).numpy()
        self.den += (share * shown).sum(dim=(0, 2, 3)).numpy()

    def result(self) -> dict[str, float]:
        out: dict[str, float] = {}
        for b, name in enumerate(BONE_NAMES):
            num = self.num[b] + self.num[N_BONES + b]
            den = self.den[b] + self.den[N_BONES + b]
            if den > 0:
                out[name] = float(num / den)
        if self.den[N_SLOTS] > 1e-9 * max(self.den.sum(), 1e-300):
            out["unweighted"] = float(self.num[N_SLOTS] / self.den[N_SLOTS])
        return out
