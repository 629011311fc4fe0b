"""Shared figure helpers: a headless pyplot, atomic PNG saving, spectrogram panels."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from handradar.atomic import atomic_path


def pyplot():
    """matplotlib.pyplot on the non-interactive Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: str | Path, dpi: int = 110) -> Path:
    """Save ``fig`` as PNG atomically and close it."""
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=dpi)
    pyplot().close(fig)
    return path


def spectrogram_panel(ax, spec: np.ndarray, title: str = "", *, cmap: str = "viridis", vmin: float = 0.0,
                      vmax: float = 1.0) -> None:
    """One (doppler, columns) spectrogram, zero Doppler in the middle row, approaching upward."""
    ax.imshow(np.asarray(spec), origin="lower", aspect="auto", cmap=cmap, vmin=vmin, vmax=vmax,
              interpolation="nearest")
    ax.set_xticks([])
    ax.set_yticks([])
    if title:
        ax.set_title(title, fontsize=7)
