"""The one-page summary of a train.py job: accuracy by variant beside real and synthetic spectrograms."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from handradar.viz.common import pyplot, save_figure, spectrogram_panel


def plot_summary(accuracy: Mapping[str, float], path: str | Path, *, chance: float | None = None,
                 pairs: Sequence[tuple[str, np.ndarray, np.ndarray]] = (), title: str = "") -> Path:
    """Accuracy per variant (bars, chance as a dashed line) and, per pair ``(gesture, real, synthetic)``
    of (Doppler, time) spectrograms in [0, 1] of the same recording, the two side by side."""
    plt = pyplot()
    names = list(accuracy)
    n_pairs = len(pairs)
    fig = plt.figure(figsize=(4.2 + 1.5 * n_pairs, 3.4), dpi=110)
    grid = fig.add_gridspec(2, 1 + n_pairs, width_ratios=[2.6] + [1.0] * n_pairs)
    ax = fig.add_subplot(grid[:, 0])
    y = np.arange(len(names))
    ax.barh(y, [accuracy[k] for k in names], color="tab:blue")
    for i, k in enumerate(names):
        ax.text(min(accuracy[k] + 0.02, 0.8), i, f"{accuracy[k]:.3f}", va="center", fontsize=7)
    if chance is not None:
        ax.axvline(chance, color="grey", ls="--", lw=1, label="chance")
        ax.legend(fontsize=7, loc="lower right")
    ax.set_yticks(y, names, fontsize=7)
    ax.invert_yaxis()
    ax.set_xlim(0, 1)
    ax.set_xlabel("test accuracy")
    ax.set_title(title or "accuracy by variant", fontsize=8)
    for j, (gesture, real, synthetic) in enumerate(pairs):
        for row, (image, kind) in enumerate(((real, "real"), (synthetic, "synthetic"))):
            spectrogram_panel(fig.add_subplot(grid[row, 1 + j]), image, f"{gesture}\n{kind}" if row == 0 else kind)
    fig.tight_layout()
    return save_figure(fig, path)
