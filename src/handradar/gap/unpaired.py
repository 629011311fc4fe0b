"""The unpaired gap report of a measured dataset: where synthetic spectrograms differ from measured ones when
no row is paired (docs/datasets.md#the-unpaired-gap-report).

Per class, each image is summarised by a few statistics of its (doppler, columns) map in [0, 1]
(:data:`STATISTICS`); the report ranks them by the standardised difference of the synthetic and the
measured rows (Cohen's d: the difference of means over the pooled standard deviation), and gives the
class-mean and class-spread images' 1 - SSIM (the unpaired fit's objective, handradar.synthesis.measured). Large
|d| names what the simulator gets wrong: its Doppler spread, the weight of the zero-Doppler band, how long the
gesture lasts, ... Given the synthetic rows with one processing step switched on alone (``alternatives``:
handradar.synthesis.measured.step_rows), it names per class the step that explains most of the difference:
the one whose class mean lies closest to the measured one, where it is closer than the fitted chain's.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np
from scipy.signal import find_peaks

from handradar.atomic import atomic_write_text
from handradar.metrics import per_example_ssim
from handradar.viz.measured import plot_class_means

ZERO_BAND = 2  # rows either side of zero Doppler counted as the zero-Doppler band
BURST_PROMINENCE = 0.3  # a burst's peak stands out of the off-band energy by this share of the image's largest
BURST_APART = 5  # columns at least between two bursts' peaks


def _weights(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Doppler row offsets from zero (rows - n // 2) and each image's Doppler profile (summed over time)."""
    n = x.shape[-2]
    rows = np.arange(n) - n // 2
    profile = x.sum(axis=-1)
    return rows, profile / np.maximum(profile.sum(axis=-1, keepdims=True), 1e-12)


def doppler_centroid(x: np.ndarray) -> np.ndarray:
    rows, p = _weights(x)
    return (p * rows).sum(axis=-1)


def doppler_spread(x: np.ndarray) -> np.ndarray:
    rows, p = _weights(x)
    centre = (p * rows).sum(axis=-1, keepdims=True)
    return np.sqrt((p * (rows - centre) ** 2).sum(axis=-1))


def zero_band_share(x: np.ndarray) -> np.ndarray:
    rows, p = _weights(x)
    return p[..., np.abs(rows) <= ZERO_BAND].sum(axis=-1)


def _off_band(x: np.ndarray) -> np.ndarray:
    """Each column's energy off the zero band (..., columns)."""
    n = x.shape[-2]
    return np.delete(x, np.arange(n // 2 - ZERO_BAND, n // 2 + ZERO_BAND + 1), axis=-2).sum(axis=-2)


def moving_share(x: np.ndarray) -> np.ndarray:
    """Share of columns whose energy off the zero band exceeds half of the image's largest such column."""
    off = _off_band(x)
    return (off > 0.5 * off.max(axis=-1, keepdims=True)).mean(axis=-1)


def _bursts(x: np.ndarray) -> list[np.ndarray]:
    """Per image, the columns where its bursts of motion peak: the maxima of the off-band energy (the column's
    background, its median over the image, taken off; smoothed over 3 columns) that stand out of it by at least
    ``BURST_PROMINENCE`` of its largest, at least ``BURST_APART`` columns apart."""
    off = _off_band(x.reshape(-1, *x.shape[-2:]))
    off = np.clip(off - np.median(off, axis=-1, keepdims=True), 0.0, None)
    kernel = np.ones(3) / 3
    out = []
    for e in off:
        e = np.convolve(e, kernel, mode="same")
        peaks, _ = find_peaks(e, prominence=BURST_PROMINENCE * max(e.max(), 1e-12), distance=BURST_APART)
        out.append(peaks)
    return out


def burst_count(x: np.ndarray) -> np.ndarray:
    """How many bursts of motion each image holds (:func:`_bursts`): a tap 1, a double-click 2, a circle its turns."""
    return np.array([len(p) for p in _bursts(x)], dtype=np.float64).reshape(x.shape[:-2])


def burst_span(x: np.ndarray) -> np.ndarray:
    """Columns from each image's first burst peak to its last (0: one burst or none): how far apart repetitions lie."""
    return np.array([p[-1] - p[0] if len(p) else 0 for p in _bursts(x)], dtype=np.float64).reshape(x.shape[:-2])


def doppler_reach(x: np.ndarray) -> np.ndarray:
    """Rows from zero Doppler out to the farthest row whose brightest pixel stands half-way from the image's median
    (its background) to its peak: how fast the fastest part of the motion gets, in Doppler rows."""
    n = x.shape[-2]
    rows = np.abs(np.arange(n) - n // 2)
    level = np.median(x, axis=(-2, -1), keepdims=True)[..., 0]
    brightest = x.max(axis=-1)
    lit = brightest > level + 0.5 * (brightest.max(axis=-1, keepdims=True) - level)
    return np.where(lit, rows, 0).max(axis=-1).astype(np.float64)


STATISTICS: dict[str, tuple[Callable[[np.ndarray], np.ndarray], str]] = {
    "mean_level": (lambda x: x.mean(axis=(-2, -1)), "mean value of the image (0: floor, 1: peak)"),
    "floor_share": (lambda x: (x <= 1e-3).mean(axis=(-2, -1)), "share of pixels at the dB floor"),
    "doppler_centroid": (doppler_centroid, "energy-weighted Doppler row offset from zero (+: approaching)"),
    "doppler_spread": (doppler_spread, "energy-weighted standard deviation of the Doppler row"),
    "zero_band_share": (zero_band_share, f"share of the energy within {ZERO_BAND} rows of zero Doppler"),
    "moving_share": (moving_share, "share of the columns holding motion off the zero band"),
    "doppler_reach": (doppler_reach, "rows from zero Doppler that the motion reaches at half the image's peak"),
    "burst_count": (burst_count, "bursts of motion off the zero band (a double-click 2, a circle its turns)"),
    "burst_span": (burst_span, "columns from the first burst's peak to the last's"),
}
MOTION_STATISTICS = ("doppler_reach", "burst_count", "burst_span")  # the report's table of the motion's own terms


def cohen_d(a: np.ndarray, b: np.ndarray) -> float:
    """(mean b - mean a) / pooled standard deviation; 0 where both are constant and equal."""
    pooled = float(np.sqrt(0.5 * (a.var(ddof=1) + b.var(ddof=1)))) if len(a) > 1 and len(b) > 1 else 0.0
    diff = float(b.mean() - a.mean())
    return diff / pooled if pooled > 0 else (0.0 if diff == 0 else float(np.sign(diff)) * np.inf)


def unpaired_gap(real_x: np.ndarray, real_y: np.ndarray, synth_x: np.ndarray, synth_y: np.ndarray,
                 classes: Sequence[str], alternatives: Mapping[str, np.ndarray] | None = None) -> dict:
    """Per class and statistic: measured and synthetic mean, Cohen's d; the class means' 1 - SSIM; ranked. With
    ``alternatives`` (step name -> the synthetic rows, in ``synth_x``'s order, with that step switched on alone):
    per class each step's class-mean 1 - SSIM (``steps``) and the step that explains most (``explained_by``: the
    smallest, where below the fitted chain's ``mean_image_gap``; else None)."""
    out = {"classes": {}, "statistics": {k: doc for k, (_, doc) in STATISTICS.items()}}
    alternatives = dict(alternatives or {})
    for c, name in enumerate(classes):
        r, s = real_x[real_y == c], synth_x[synth_y == c]
        if not len(r) or not len(s):
            raise ValueError(f"class {name!r} has {len(r)} measured and {len(s)} synthetic rows: both are needed")
        stats = {}
        for key, (fn, _) in STATISTICS.items():
            a, b = fn(r), fn(s)
            stats[key] = {"measured": float(a.mean()), "synthetic": float(b.mean()), "d": cohen_d(a, b)}
        gaps = 1.0 - per_example_ssim(np.stack([r.mean(axis=0), r.std(axis=0)]), np.stack([s.mean(axis=0), s.std(axis=0)]))
        entry = {"mean_image_gap": float(gaps[0]), "spread_image_gap": float(gaps[1]),
                 "n_measured": int(len(r)), "n_synthetic": int(len(s)), "statistics": stats}
        if alternatives:
            means = np.stack([a[synth_y == c].mean(axis=0) for a in alternatives.values()])
            steps = 1.0 - per_example_ssim(np.broadcast_to(r.mean(axis=0), means.shape).copy(), means)
            entry["steps"] = {k: float(g) for k, g in zip(alternatives, steps)}
            best = min(entry["steps"], key=entry["steps"].get)
            entry["explained_by"] = best if entry["steps"][best] < entry["mean_image_gap"] else None
        out["classes"][name] = entry
    ranked = sorted(((abs(v["d"]), cls, key) for cls, e in out["classes"].items() for key, v in e["statistics"].items()),
                    reverse=True)
    out["largest"] = [{"class": cls, "statistic": key, **out["classes"][cls]["statistics"][key]}
                      for _, cls, key in ranked[:8]]
    return out


def markdown(report: dict) -> str:
    """The report as a markdown page: the class-mean gaps, the motion's own terms, then the statistics that differ
    most."""
    lines = ["# Unpaired gap: measured vs synthetic", "",
             "Per class: 1 - SSIM of the class-mean and class-spread images (0: identical; the fit's objective).",
             "Then the statistics whose synthetic and measured values differ most (Cohen's d: synthetic minus",
             "measured, in pooled standard deviations).", "",
             "| class | measured rows | synthetic rows | 1 - SSIM of the means | 1 - SSIM of the spreads |",
             "|---|---|---|---|---|"]
    lines += [f"| {c} | {e['n_measured']} | {e['n_synthetic']} | {e['mean_image_gap']:.3f} | {e['spread_image_gap']:.3f} |"
              for c, e in report["classes"].items()]
    if any("steps" in e for e in report["classes"].values()):
        lines += ["", "Which processing step explains most of each class's difference: each switched on alone over the",
                  "fitted chain, the class means' 1 - SSIM (none: no step brings the synthetic mean closer).", "",
                  "| class | fitted chain | step explaining most | its 1 - SSIM |", "|---|---|---|---|"]
        lines += [f"| {c} | {e['mean_image_gap']:.3f} | {e['explained_by'] or 'none'} | "
                  f"{e['steps'][e['explained_by']] if e['explained_by'] else min(e['steps'].values()):.3f} |"
                  for c, e in report["classes"].items()]
    lines += ["", "The motion in its own terms, per class: measured / synthetic means over the rows.", "",
              "| class | " + " | ".join(MOTION_STATISTICS) + " |", "|---|" + "---|" * len(MOTION_STATISTICS)]
    lines += [f"| {c} | " + " | ".join(f"{e['statistics'][k]['measured']:.1f} / {e['statistics'][k]['synthetic']:.1f}"
                                      for k in MOTION_STATISTICS) + " |" for c, e in report["classes"].items()]
    lines += ["", "| class | statistic | measured | synthetic | d |", "|---|---|---|---|---|"]
    lines += [f"| {r['class']} | {r['statistic']} | {r['measured']:.3f} | {r['synthetic']:.3f} | {r['d']:+.2f} |"
              for r in report["largest"]]
    lines += ["", "Statistics:", *[f"- `{k}`: {doc}" for k, doc in report["statistics"].items()], ""]
    return "\n".join(lines)


def write_unpaired_gap(real_x: np.ndarray, real_y: np.ndarray, synth_x: np.ndarray, synth_y: np.ndarray,
                       classes: Sequence[str], out_dir: str | Path,
                       alternatives: Mapping[str, np.ndarray] | None = None, approaching: str = "high") -> list[Path]:
    """``unpaired_gap.json``, ``unpaired_gap.md`` and ``figures/class_means.png`` in ``out_dir``; ``approaching``:
    which end of the rows' Doppler axis approaches (the figure draws the high rows up and says which that is)."""
    out_dir = Path(out_dir)
    report = unpaired_gap(real_x, real_y, synth_x, synth_y, classes, alternatives)
    atomic_write_text(out_dir / "unpaired_gap.json", json.dumps(report, indent=1))
    atomic_write_text(out_dir / "unpaired_gap.md", markdown(report))
    up = "approaching" if approaching == "high" else "receding (the dataset's approaching end is low)"
    png = plot_class_means(real_x, real_y, synth_x, synth_y, classes, out_dir / "figures" / "class_means.png",
                           title=f"measured vs synthetic, per class (Doppler up: {up}; time right)")
    return [out_dir / "unpaired_gap.json", out_dir / "unpaired_gap.md", png]
