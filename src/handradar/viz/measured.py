"""The unpaired gap figure of a measured dataset: per class, measured and synthetic mean and spread images."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from handradar.viz.common import pyplot, save_figure, spectrogram_panel


def plot_class_means(real_x: np.ndarray, real_y: np.ndarray, synth_x: np.ndarray, synth_y: np.ndarray,
                     classes: Sequence[str], out: str | Path, *, title: str = "") -> Path:
    """One row per class: measured mean, synthetic mean, measured spread (std), synthetic spread.

    Spectrograms (N, doppler, columns) in [0, 1], zero Doppler on the middle row, approaching up. The spreads
    share one colour scale (0 to the largest std of either) so that they compare."""
    plt = pyplot()
    n = len(classes)
    stds = [(real_x[real_y == c].std(axis=0), synth_x[synth_y == c].std(axis=0)) for c in range(n)]
    top = max(float(max(a.max(), b.max())) for a, b in stds) or 1.0
    fig, axes = plt.subplots(n, 4, figsize=(6.4, 1.45 * n + 0.5), squeeze=False)
    for c, name in enumerate(classes):
        r, s = real_x[real_y == c], synth_x[synth_y == c]
        heads = [f"measured mean ({len(r)})", f"synthetic mean ({len(s)})", "measured std", "synthetic std"]
        for k, (img, vmax) in enumerate([(r.mean(axis=0), 1.0), (s.mean(axis=0), 1.0), (stds[c][0], top),
                                         (stds[c][1], top)]):
            spectrogram_panel(axes[c, k], img, heads[k] if c == 0 else "", vmax=vmax)
        axes[c, 0].set_ylabel(name, fontsize=7)
    fig.suptitle(title or "measured vs synthetic, per class (Doppler up: approaching; time right)", fontsize=8)
    fig.tight_layout()
    return save_figure(fig, out)
