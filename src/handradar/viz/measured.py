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


def plot_measured_curve(rows: dict[str, dict[str, list[float]]], out: str | Path, *,
                        anchors: dict[str, float] | None = None, title: str = "") -> Path:
    """Accuracy against real rows per class, one panel per test split: ``rows`` maps (k, split) row labels of the
    measured table ("8 per class, A {measured: NAME}") to column -> values over seeds; mean ± std, the seeds' count
    in the legend. ``anchors``: split -> a published figure drawn as a dashed line."""
    points: dict[str, dict[str, dict[str, list[float]]]] = {}  # split -> column -> k -> values
    for label, cells in rows.items():
        k, rest = label.split(" per class, ", 1)
        split = rest.split(" ", 1)[0]
        for column, values in cells.items():
            points.setdefault(split, {}).setdefault(column, {})[k] = values
    ks = sorted({k for s in points.values() for c in s.values() for k in c},
                key=lambda k: (k == "all", float(k) if k != "all" else 0.0))
    plt = pyplot()
    fig, axes = plt.subplots(1, max(len(points), 1), figsize=(5.2 * max(len(points), 1), 3.8), sharey=True, squeeze=False)
    for ax, (split, columns) in zip(axes[0], sorted(points.items())):
        for column, by_k in columns.items():
            x = [ks.index(k) for k in ks if k in by_k]
            mean = [float(np.mean(by_k[k])) for k in ks if k in by_k]
            std = [float(np.std(by_k[k])) for k in ks if k in by_k]
            n = sorted({len(by_k[k]) for k in by_k})
            seeds = f"{n[0]}" if len(n) == 1 else f"{n[0]}-{n[-1]}"
            ax.errorbar(x, mean, yerr=std, marker="o", capsize=3, label=f"{column} ({seeds} seed{'s' * (n[-1] > 1)})")
        if anchors and split in anchors:
            ax.axhline(anchors[split], color="k", linestyle="--", linewidth=1, label="published anchor")
        ax.set_xticks(range(len(ks)), ks)
        ax.set_xlabel("real rows per class")
        ax.set_title(f"test split {split}")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("accuracy")
    axes[0][-1].legend(fontsize=7, loc="lower right")
    if title:
        fig.suptitle(title)
    return save_figure(fig, out)
