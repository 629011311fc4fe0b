"""Figures of the hybrid synthesis: measured vs modelled vs enhanced, the per-reflection-point
decomposition of a spectrogram (the paper's decomposition figure), learned weights over time."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from handradar.hand.skeleton import BONE_NAMES, HANDS
from handradar.radar.chain import profile_power
from handradar.viz.common import pyplot, save_figure, spectrogram_panel

SLOT_NAMES = tuple(f"{h[0].upper()} {b}" for h in HANDS for b in BONE_NAMES)


def plot_comparison(measured: np.ndarray, model: np.ndarray, enhanced: np.ndarray, names: Sequence[str],
                    path: str | Path) -> Path:
    """Rows: measured, modelling only, modelling + RadarWeightNet; one column per example."""
    plt = pyplot()
    n = len(names)
    fig, axes = plt.subplots(3, n, figsize=(1.3 * n + 0.8, 4.6), squeeze=False)
    for j in range(n):
        for i, (stack, label) in enumerate(((measured, "measured"), (model, "model"), (enhanced, "enhanced"))):
            spectrogram_panel(axes[i, j], stack[j], names[j] if i == 0 else "")
            if j == 0:
                axes[i, j].set_ylabel(label, fontsize=8)
    fig.suptitle("measured vs modelling only vs modelling + RadarWeightNet", fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_decomposition(sim, pairs, weights: np.ndarray, path: str | Path, *, title: str = "", top: int = 11) -> Path:
    """Spectrogram of each reflection point alone (weighted, on the full spectrogram's scale) for
    the ``top`` strongest slots of one example, next to the full enhanced spectrogram."""
    plt = pyplot()
    w = torch.as_tensor(weights)[None]  # (1, T, 38)
    prof = pairs.profiles  # (1, 39, F, L, Ch, bins)
    with torch.no_grad():
        full_sig = sim.combine(prof, w)
        full = sim.render(prof, w)[0].numpy()
        singles = []
        for k in range(w.shape[-1]):  # each bone slot alone: zero every other slot's profile
            only = torch.zeros_like(prof)
            only[:, k] = prof[:, k]
            singles.append(sim.combine(only, w))
        energies = [float(s.abs().square().sum()) for s in singles]
        total_energy = sum(energies)
    order = [int(k) for k in np.argsort(energies)[::-1][:top] if energies[k] > 0]
    fig, axes = plt.subplots(1, len(order) + 1, figsize=(1.25 * (len(order) + 1), 2.2), squeeze=False)
    spectrogram_panel(axes[0, 0], full, "all points")

    total = profile_power(full_sig, sim.chain)[0].amax().item()
    for ax, k in zip(axes[0, 1:], order):
        p = profile_power(singles[k], sim.chain)[0].numpy()
        db = 10 * np.log10(p / total + 1e-30)
        spectrogram_panel(ax, np.clip((db + sim.chain.dynamic_range_db) / sim.chain.dynamic_range_db, 0, 1),
                          f"{SLOT_NAMES[k]}\n{100 * energies[k] / max(total_energy, 1e-30):.0f}%")
    fig.suptitle(f"per-reflection-point decomposition {title}".strip(), fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_weights(weights: np.ndarray, mask: np.ndarray, path: str | Path, *, title: str = "") -> Path:
    """Learned weight of each bone slot over the skeleton steps (tracked hands only)."""
    plt = pyplot()
    w = np.asarray(weights, dtype=np.float64).copy()  # (T, 38)
    for h in range(2):
        w[~np.asarray(mask)[:, h], h * 19:(h + 1) * 19] = np.nan
    keep = ~np.all(np.isnan(w), axis=0)
    fig, ax = plt.subplots(figsize=(7, 0.18 * keep.sum() + 1.2))
    im = ax.imshow(w[:, keep].T, aspect="auto", cmap="magma", interpolation="nearest")
    ax.set_yticks(range(int(keep.sum())), [n for n, k in zip(SLOT_NAMES, keep) if k], fontsize=6)
    ax.set_xlabel("skeleton step")
    ax.set_title(f"RadarWeightNet weights {title}".strip(), fontsize=9)
    fig.colorbar(im, ax=ax, fraction=0.03)
    fig.tight_layout()
    return save_figure(fig, path)
