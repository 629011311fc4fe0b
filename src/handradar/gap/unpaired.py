"""The unpaired gap report of a measured dataset: where synthetic spectrograms differ from measured ones when
no row is paired (docs/datasets.md#the-unpaired-gap-report).

Per class, each image is summarised by a few statistics of its (doppler, columns) map in [0, 1]
(handradar.metrics.STATISTICS); the report ranks them by the standardised difference of the synthetic and the
measured rows (Cohen's d: the difference of means over the pooled standard deviation), and gives the
class-mean and class-spread images' 1 - SSIM (the unpaired fit's objective, handradar.synthesis.measured). Large
|d| names what the simulator gets wrong: its Doppler spread, the weight of the zero-Doppler band, how long the
gesture lasts, ... Given the synthetic rows with one processing step switched on alone (``alternatives``:
handradar.synthesis.measured.one_step_rows), it names per class the step that explains most of the difference:
the one whose class mean lies closest to the measured one, where it is closer than the fitted chain's.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from handradar.atomic import atomic_write_text
from handradar.metrics import MOTION_STATISTICS, STATISTICS, cohen_d, per_example_ssim
from handradar.viz.measured import plot_class_means

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
