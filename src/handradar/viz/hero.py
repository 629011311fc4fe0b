"""``python -m handradar.viz.hero``: the README's first figure, one gesture three ways.

Left: the Leap skeleton window of one reference-world recording (the hand at the window's middle,
fingertip paths over the 1.6 s window). Middle: the spectrogram the paper's simulator makes from that
skeleton. Right: the reference world's own spectrogram of the same recording, the stand-in for a
measurement. Both spectrograms are 64 Doppler rows x 32 columns in [0, 1], zero Doppler in the
middle, an approaching hand above it. Written to docs/figures/hero.png (about 10 s on one core).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from matplotlib.ticker import MaxNLocator

from handradar.config import VERSION_BASE, config_dir
from handradar.hand.skeleton import BONES
from handradar.metrics import per_example_ssim
from handradar.provenance import REPO_ROOT
from handradar.sim.factory import SimFactory
from handradar.viz.common import pyplot, save_figure, spectrogram_panel
from handradar.world import RecordingSpec, fast_example, world_config

FINGERTIPS = (4, 8, 12, 16, 20)  # canonical (MediaPipe) joint order


def hero_panels(gesture: str = "circle", subject: int = 0, angle_deg: float = 0.0,
                overrides: list[str] | None = None) -> dict:
    """Skeleton window, simulated and reference-world spectrogram of one recording of the default world.

    Returns {"skeleton": (T, 2, 21, 3) m, "hand_mask": (T, 2), "simulated", "world": (64, 32) in [0, 1],
    "ssim": float, "title": str}. ``overrides``: Hydra overrides of conf/world.yaml (e.g. world.seed=3).
    """
    with initialize_config_dir(str(config_dir()), version_base=VERSION_BASE):
        cfg = compose("world", overrides=["out=unused", *(overrides or [])])
    radar, chain, world = instantiate(cfg.radar), instantiate(cfg.chain), world_config(cfg.world)
    row = fast_example(world, radar, chain, RecordingSpec(gesture, subject, angle_deg, 0))
    skeleton, mask = torch.as_tensor(row["skeleton"])[None], torch.as_tensor(row["hand_mask"])[None]
    with torch.no_grad():  # the paper's simulator: no effects, the paper's cylinder RCS
        simulated = SimFactory(radar, chain, skeleton_rate_hz=world.skeleton_rate_hz)()(skeleton, mask)
    measured = torch.as_tensor(row["spectrogram"])[None]
    return {"skeleton": row["skeleton"], "hand_mask": row["hand_mask"], "simulated": simulated[0].numpy(),
            "world": row["spectrogram"], "ssim": float(per_example_ssim(measured, simulated)[0]),
            "title": f"{gesture}, subject {subject + 1}, {angle_deg:+.0f} deg"}


def _skeleton_panel(ax, skeleton: np.ndarray, mask: np.ndarray) -> None:
    """The tracked hands at the window's middle step (bones), fingertip paths over the window; cm."""
    t = len(skeleton) // 2
    for h in range(skeleton.shape[1]):
        if not mask[:, h].any():
            continue
        step = t if mask[t, h] else int(np.flatnonzero(mask[:, h])[0])
        joints = skeleton[step, h] * 100.0
        for a, b in BONES:
            ax.plot(*joints[[a, b]].T, color="#1f3b73", lw=1.4)
        ax.scatter(*joints.T, s=5, color="#1f3b73")
        for tip in FINGERTIPS:
            path = np.where(mask[:, h, None], skeleton[:, h, tip], np.nan) * 100.0
            ax.plot(*path.T, color="#e07020", lw=0.8, alpha=0.8)
    pts = skeleton[mask] * 100.0  # (n, 21, 3): equal scales on the three axes, so the hand keeps its shape
    centre, half = (pts.max((0, 1)) + pts.min((0, 1))) / 2, (pts.max((0, 1)) - pts.min((0, 1))).max() / 2
    for set_lim, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre, strict=True):
        set_lim(c - half, c + half)
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.set_major_locator(MaxNLocator(3))
    ax.set_xlabel("x (cm)", fontsize=7, labelpad=-2)
    ax.set_ylabel("y (cm)", fontsize=7, labelpad=-2)
    ax.set_zlabel("height above radar (cm)", fontsize=7, labelpad=-2)
    ax.tick_params(labelsize=6, pad=0)
    ax.set_box_aspect(None, zoom=1.3)  # the 3-D box fills its panel
    ax.set_title("Leap skeleton (orange: fingertip paths)", fontsize=8)


def draw_hero(panels: dict, out: str | Path) -> Path:
    """The three-panel figure of :func:`hero_panels`, saved as PNG (atomic)."""
    plt = pyplot()
    fig = plt.figure(figsize=(10.0, 3.2))
    grid = fig.add_gridspec(1, 3, width_ratios=(1.25, 1, 1))
    ax = fig.add_subplot(grid[0], projection="3d")
    _skeleton_panel(ax, panels["skeleton"], panels["hand_mask"])
    for i, (key, title) in enumerate((("simulated", "simulated from the skeleton\n(the paper's simulator)"),
                                      ("world", "reference world\n(stand-in for a measurement)"))):
        a = fig.add_subplot(grid[1 + i])
        spectrogram_panel(a, panels[key], title)
        a.title.set_fontsize(8)
        a.set_xlabel("time: 32 columns = 1.6 s", fontsize=7)
        a.set_ylabel("Doppler: 64 rows, approaching up", fontsize=7)
    fig.suptitle(f"{panels['title']}: SSIM simulated vs reference world {panels['ssim']:.3f}", fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    return save_figure(fig, out, dpi=90)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=REPO_ROOT / "docs" / "figures" / "hero.png")
    parser.add_argument("--gesture", default="circle")
    parser.add_argument("--subject", type=int, default=0)
    parser.add_argument("--angle", type=float, default=0.0)
    parser.add_argument("overrides", nargs="*", help="Hydra overrides of conf/world.yaml, e.g. world.seed=3")
    args = parser.parse_args(argv)
    print(draw_hero(hero_panels(args.gesture, args.subject, args.angle, args.overrides), args.out))


if __name__ == "__main__":
    main()
