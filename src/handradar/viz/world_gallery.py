"""``python -m handradar.viz.world_gallery``: reference-world spectrograms per gesture and per effect.

Rows 1-2: the ten gestures in the default world, on boresight and at +30 deg. Rows 3-4: one gesture
per effect with the effect as in the default world and toggled (off; iq_imbalance: on). The red
line is the hands' mean radial velocity computed from the skeleton the Leap recorded (what a
simulator would be fed), so the Leap effects (sync offset, jitter, calibration) show as a shifted
or noisy line over an unchanged spectrogram. Written to docs/figures/world_gallery.png.
"""

from __future__ import annotations

import argparse
import dataclasses
import warnings
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from hydra import compose, initialize_config_dir  # noqa: E402
from hydra.utils import instantiate  # noqa: E402

from handradar.config import VERSION_BASE, config_dir  # noqa: E402
from handradar.provenance import REPO_ROOT  # noqa: E402
from handradar.radar.chain import velocity_axis_m_s  # noqa: E402
from handradar.vocab import GESTURES  # noqa: E402
from handradar.world import RecordingSpec, fast_example, world_config  # noqa: E402

# effect -> (gesture, angle) where it shows best
SHOWCASE = {
    "occlusion": ("hand_merge", 0.0), "palm": ("slide", 0.0), "forearm": ("circle", 0.0),
    "multipath": ("double_hand_clap", 0.0), "antenna_pattern": ("slide", 30.0), "noise": ("finger_wave", 0.0),
    "sync_offset": ("slide", 0.0), "tracking_jitter": ("circle", 0.0), "calibration": ("double_hand_circle", 30.0),
    "iq_imbalance": ("circle", 0.0),
}


def _velocity_rows(row: dict, radar, chain, rate_hz: float) -> np.ndarray:
    """Mean radial velocity of the recorded hands per skeleton step, as a (fractional) Doppler row."""
    pos, mask = row["skeleton"], row["hand_mask"]
    r = np.where(mask, np.linalg.norm(pos, axis=-1).mean(-1), np.nan)  # (T, 2); gaps where untracked
    v = -np.gradient(r, 1.0 / rate_hz, axis=0)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN steps (dropped frames) stay NaN
        v = np.nanmean(v, axis=1)
    vel = velocity_axis_m_s(radar, chain)
    return np.where(np.isfinite(v), np.interp(v, vel, np.arange(len(vel))), np.nan)


def _panel(ax, row: dict, title: str, radar, chain, rate_hz: float) -> None:
    spec = row["spectrogram"]
    ax.imshow(spec, origin="lower", aspect="auto", cmap="viridis", vmin=0, vmax=1, interpolation="nearest")
    rows = _velocity_rows(row, radar, chain, rate_hz)
    x = (np.arange(len(rows)) + 0.5) / len(rows) * spec.shape[1] - 0.5
    ax.plot(x, rows, color="#ff3030", lw=1.0, alpha=0.9)
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(title, fontsize=7)


def gallery(out: Path, overrides: list[str] | None = None, subject: int = 0) -> Path:
    with initialize_config_dir(str(config_dir()), version_base=VERSION_BASE):
        cfg = compose("world", overrides=["out=unused", *(overrides or [])])
    world, radar, chain = world_config(cfg.world), instantiate(cfg.radar), instantiate(cfg.chain)
    fig, axes = plt.subplots(4, 10, figsize=(15, 6.6))
    for j, g in enumerate(GESTURES):
        for i, angle in enumerate((0.0, 30.0)):
            row = fast_example(world, radar, chain, RecordingSpec(g, subject, angle, 0))
            _panel(axes[i, j], row, f"{g}\n{angle:+.0f} deg" if i == 0 else f"{angle:+.0f} deg", radar, chain,
                   world.skeleton_rate_hz)
    for j, (effect, (g, angle)) in enumerate(SHOWCASE.items()):
        spec = RecordingSpec(g, subject, angle, 0)
        state = getattr(world.effects, effect).enabled
        toggled = dataclasses.replace(world, effects=world.effects.with_(effect, enabled=not state))
        for i, (w, on) in enumerate(((world, state), (toggled, not state))):
            row = fast_example(w, radar, chain, spec)
            _panel(axes[2 + i, j], row, f"{effect} {'on' if on else 'off'}\n{g} {angle:+.0f}", radar, chain,
                   world.skeleton_rate_hz)
    fig.text(0.005, 0.75, "gestures (default world)", rotation=90, va="center", fontsize=8)
    fig.text(0.005, 0.27, "effects: default / toggled", rotation=90, va="center", fontsize=8)
    fig.suptitle("handradar reference world: 64 Doppler bins x 32 columns (1.6 s); red: radial velocity "
                 "from the Leap skeleton", fontsize=9)
    fig.tight_layout(rect=(0.01, 0, 1, 0.97))
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=72)
    plt.close(fig)
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=REPO_ROOT / "docs" / "figures" / "world_gallery.png")
    parser.add_argument("--subject", type=int, default=0)
    parser.add_argument("overrides", nargs="*", help="Hydra overrides of conf/world.yaml, e.g. world.seed=3")
    args = parser.parse_args(argv)
    print(gallery(args.out, args.overrides, args.subject))


if __name__ == "__main__":
    main()
