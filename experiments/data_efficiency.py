"""The data-efficiency curve from the MLflow runs of ``+experiment=data_efficiency`` (``make data-efficiency-figure``).

    python -m experiments.data_efficiency [--tracking-uri URI] [--log-dir DIR] [--out FILE]

Test accuracy against the real training rows per gesture (``split.per_class``), mean ± std over
seeds: radar only; + synthetic data from the simulator fitted on those rows, without and with
RadarWeightNet (``'variants=[enhanced_synth]'``, its guard fitted on the same rows); synthetic only with
that simulator; synthetic only with the paper's unfitted simulator (``synth.fit_sim=none``: no real
row involved, drawn at 0); the pool's real spectrograms as the ceiling. Prints the curve as a
markdown table, then the fitted simulator at each size per seed (its RCS exponent, the effects it kept
and their values, and its held-out SSIM before and after the effects: from the run's ``synth.fitted.*``
params, or its job's ``fitted_sim.yaml`` and ``fit_report.json`` under ``--log-dir``), then the
figure's path.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections import defaultdict
from collections.abc import Iterable, Mapping
from pathlib import Path

from omegaconf import OmegaConf

from handradar.provenance import REPO_ROOT
from handradar.vocab import GESTURES
from handradar.runs.tables import (
    DEFAULT_TRACKING_URI,
    DIRTY_MARK,
    DIRTY_NOTE,
    data_setting,
    dirty,
    load_records,
    mean_std,
    stats,
    synthesis_setting,
)
from handradar.viz.common import pyplot, save_figure

TASK = "data_efficiency"
# curve -> (metric, simulator fitted?)
CURVES = {
    "radar only": ("test/acc_radar_only", None),
    "+ synthetic (fitted simulator)": ("test/acc_model_synth", True),
    "+ synthetic (fitted simulator + RadarWeightNet)": ("test/acc_enhanced_synth", True),
    "synthetic only (fitted simulator)": ("test/acc_model_synth_only", True),
    "synthetic only (paper's simulator)": ("test/acc_model_synth_only", False),
    "real pool (ceiling)": ("test/acc_radar_pool", None),
}
CEILING = "real pool (ceiling)"  # the pool's real rows do not depend on k: one value per seed, kept at 0


def ours(rec: Mapping, data: str) -> bool:
    """A data-efficiency run on ``data`` (a :func:`data_setting` label; "" the default world) whose synthetic
    rows come from the fitted simulator (``synth.fit_sim=effects``) or the paper's (``none``), one draw per
    row: the curve never mixes in another synthesis setting."""
    p = rec["params"]
    return (p.get("task_name") == TASK and p.get("split.per_class") not in (None, "None")
            and data_setting(p, rec.get("tags")).strip() == data.strip()
            and synthesis_setting(p) in ("", " [fitted: effects]"))


def data_labels(records: Iterable[Mapping]) -> list[str]:
    """The data sets (:func:`data_setting` labels, "" the default world) that data-efficiency runs used."""
    return sorted({data_setting(r["params"], r.get("tags")).strip() for r in records
                   if r["params"].get("task_name") == TASK})


def _counted(records: Iterable[Mapping], data: str) -> dict[str, dict[int, dict[str, tuple[float, Mapping]]]]:
    """{curve: {point: {seed: (accuracy, the record it comes from)}}}: :func:`seed_points` with each value's run."""
    out: dict[str, dict[int, dict[str, tuple[float, Mapping]]]] = defaultdict(lambda: defaultdict(dict))
    for rec in records:
        p, m = rec["params"], rec["metrics"]
        if not ours(rec, data):
            continue
        k = int(float(p["split.per_class"]))
        fitted = p.get("synth.fit_sim", "none") not in ("none", "None")
        for name, (metric, wants_fit) in CURVES.items():
            point = 0 if wants_fit is False or name == CEILING else k
            if metric in m and (wants_fit is None or wants_fit == fitted):
                out[name][point].setdefault(str(p.get("seed")), (float(m[metric]), rec))
    return {name: dict(sorted(points.items())) for name, points in out.items()}


def seed_points(records: Iterable[Mapping], data: str = "") -> dict[str, dict[int, dict[str, float]]]:
    """{curve: {rows per gesture: {seed: accuracy}}} of the data-efficiency runs on ``data`` among
    ``records`` (``{"params": flat config, "metrics": {...}}``, latest first: the latest run's value per
    curve, point and seed); the paper's simulator's points, and the ceiling's (one per seed), sit at 0."""
    return {name: {k: {seed: value for seed, (value, _) in by_seed.items()} for k, by_seed in points.items()}
            for name, points in _counted(records, data).items()}


def dirty_points(records: Iterable[Mapping], data: str = "") -> set[tuple[str, int]]:
    """The (curve, point) pairs of :func:`seed_points` with a value from a working tree with uncommitted
    changes (its record's ``provenance`` commit)."""
    return {(name, k) for name, points in _counted(records, data).items() for k, by_seed in points.items()
            if any(dirty(rec.get("provenance", {}).get("commit", "")) for _, rec in by_seed.values())}


def curves(records: Iterable[Mapping], data: str = "") -> dict[str, dict[int, list[float]]]:
    """{curve: {rows per gesture: [accuracy per seed]}}: :func:`seed_points` without the seeds."""
    return {name: {k: list(by_seed.values()) for k, by_seed in points.items()}
            for name, points in seed_points(records, data).items()}


def _state_file(rec: Mapping, log_dir: Path | None, name: str) -> dict | None:
    """A file of the run's job state folder (fitted_sim.yaml, fit_report.json), read, if it is there."""
    job = rec.get("tags", {}).get("handradar.job_hash")
    path = None if log_dir is None or job is None else log_dir / TASK / "state" / job / name
    if path is None or not path.is_file():
        return None
    return OmegaConf.to_container(OmegaConf.load(path), resolve=True)


def _described(p: Mapping, fitted: Mapping | None, report: Mapping | None = None) -> str:
    """``e 0.25; sync_offset (offset_s 0.02), ...; SSIM 0.91 -> 0.93``: the fitted RCS exponent, the effects
    with their values, and the fit's held-out SSIM before and after them (its fit_report, when there)."""
    if fitted is None:
        exponent = p.get("synth.fitted.rcs_exponent")
        text = (f"e {float(exponent):g}; " if exponent is not None else "") + p["synth.fitted.effects"]
    else:
        effects = [f"{e} ({', '.join(f'{k} {v:g}' for k, v in fitted.get('effect_params', {}).get(e, {}).items())})"
                   for e in fitted.get("effects", [])]
        text = f"e {float(fitted.get('rcs_exponent', 1.0)):g}; " + (", ".join(effects) or "-")
    if report is not None:
        text += f"; SSIM {report['baseline']['ssim']:.3f} -> {report['after']['ssim']:.3f}"
    return text


def fitted_effects(records: Iterable[Mapping], log_dir: Path | None = None, data: str = "") -> dict[int, list[str]]:
    """{rows per gesture: the fitted simulator, one entry per seed: its RCS exponent and kept effects
    ("-": none), with their values where the job's fitted_sim.yaml is under ``log_dir``}."""
    out: dict[int, dict[str, str]] = defaultdict(dict)
    for rec in records:  # latest first: the latest run per size and seed
        p = rec["params"]
        if ours(rec, data) and "synth.fitted.effects" in p:
            described = _described(p, _state_file(rec, log_dir, "fitted_sim.yaml"),
                                   _state_file(rec, log_dir, "fit_report.json"))
            out[int(float(p["split.per_class"]))].setdefault(str(p.get("seed")), described)
    return {k: [f"seed {s}: {d}" for s, d in sorted(v.items())] for k, v in sorted(out.items())}


RWN, MODEL = "+ synthetic (fitted simulator + RadarWeightNet)", "+ synthetic (fitted simulator)"


def rwn_minus_model(records: Iterable[Mapping], data: str = "") -> dict[int, dict[str, float]]:
    """{rows per gesture: {seed: + RadarWeightNet minus + model-based accuracy}}, paired within a seed (each
    from its latest run; the two variants may come from separate jobs on the same split)."""
    pts = seed_points(records, data)
    rwn, model = pts.get(RWN, {}), pts.get(MODEL, {})
    out = {k: {s: v - model[k][s] for s, v in sorted(rwn[k].items()) if s in model.get(k, {})} for k in rwn}
    return {k: d for k, d in out.items() if d}


def markdown(data: Mapping[str, Mapping[int, list[float]]], effects: Mapping[int, list[str]],
             differences: Mapping[int, Mapping[str, float]] | None = None,
             dirty_at: Iterable[tuple[str, int]] = ()) -> str:
    """The curve's table; with ``differences`` (:func:`rwn_minus_model`), a row of them per seed and the
    sizes where one falls below 0 by more than the larger seed spread of the two curves. A value from a dirty
    tree (``dirty_at``: :func:`dirty_points`) is marked."""
    sizes = sorted({k for name, points in data.items() if name != CEILING for k in points})
    marked = set(dirty_at)

    def cell(name: str, k: int) -> str:
        return mean_std(data[name][k]) + (f" {DIRTY_MARK}" if (name, k) in marked else "")

    lines = ["| real rows per gesture | " + " | ".join(str(k) for k in sizes) + " |", "|---|" + "---|" * len(sizes)]
    for name in CURVES:
        if name in data and name != CEILING:
            cells = [cell(name, k) if k in data[name] else "–" for k in sizes]
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
    if differences:
        cells = [", ".join(f"s{seed} {d:+.3f}" for seed, d in sorted(differences[k].items(), key=lambda kv: int(kv[0])))
                 if differences.get(k) else "–" for k in sizes]
        lines.append("| RadarWeightNet minus model-based, per seed | " + " | ".join(cells) + " |")
        harm, unjudged = [], []
        for k, d in differences.items():
            spreads = [sd for name in (RWN, MODEL) if not math.isnan(sd := stats(data.get(name, {}).get(k, []))[1])]
            if not spreads:  # fewer than 2 seeds on both curves: no spread to judge by
                unjudged.append(str(k))
            elif d and min(d.values()) < -max(spreads):
                harm.append(f"{k} ({min(d.values()):+.3f} against a spread of {max(spreads):.3f})")
        lines += ["", "RadarWeightNet below model-based by more than the larger seed spread at: "
                  + (", ".join(harm) if harm else "no size") + "."
                  + (f" Too few seeds to judge at: {', '.join(unjudged)}." if unjudged else "")]
    if CEILING in data:
        lines += ["", f"The {CEILING}, trained on the pool's real rows whatever k: {cell(CEILING, 0)}."]
    if effects:
        lines += ["", "| real rows per gesture | effects the fitted simulator kept |", "|---|---|"]
        lines += [f"| {k} | {'; '.join(v)} |" for k, v in effects.items()]
    if marked:
        lines += ["", DIRTY_NOTE]
    return "\n".join(lines) + "\n"


def plot(data: Mapping[str, Mapping[int, list[float]]], path: str | Path, *, chance: float | None = None) -> Path:
    """Accuracy against real rows per gesture (log axis; 0 drawn at the left edge), mean ± std bars."""
    fig, ax = pyplot().subplots(figsize=(6.0, 3.8), dpi=120)
    sizes = sorted({k for name, pts in data.items() for k in pts if k > 0})
    zero_x = (sizes[0] / 2) if sizes else 0.5
    for name in (n for n in CURVES if n in data):  # a fixed order: the same colour for a curve in every figure
        points = data[name]
        ks = sorted(points)
        xs = [k if k > 0 else zero_x for k in ks]
        m = [stats(points[k])[0] for k in ks]
        s = [stats(points[k])[1] if len(points[k]) > 1 else 0.0 for k in ks]
        if name == CEILING:
            mean = stats([v for k in ks for v in points[k]])[0]
            ax.axhline(mean, color="black", lw=1, ls=":", label=f"{name}: {mean:.3f}")
        elif ks == [0]:
            ax.errorbar(xs, m, yerr=s, fmt="s", capsize=3, label=name)
        else:
            ax.errorbar(xs, m, yerr=s, marker="o", capsize=3, label=name)
    if chance is not None:
        ax.axhline(chance, color="grey", lw=1, ls="--", label="chance")
    ax.set_xscale("log", base=2)
    ticks = [zero_x, *sizes]
    ax.set_xticks(ticks, ["0", *(str(k) for k in sizes)])
    ax.set_xlabel("real training rows per gesture")
    ax.set_ylabel("test accuracy")
    ax.set_ylim(0, 1)
    ax.legend(fontsize=7, loc="upper center", ncol=2)  # the band above the ceiling is empty
    fig.tight_layout()
    return save_figure(fig, path, dpi=120)


def main(argv: list[str] | None = None) -> Path:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tracking-uri", default=DEFAULT_TRACKING_URI)
    ap.add_argument("--log-dir", type=Path, default=REPO_ROOT / "logs", help="where the jobs' state folders are")
    ap.add_argument("--out", type=Path, default=REPO_ROOT / "docs" / "figures" / "data_efficiency.png")
    ap.add_argument("--data", default="", help="the runs' data, as make tables labels it (e.g. '{recordings: mine}'); "
                                               "default: the default reference world")
    args = ap.parse_args(argv)
    records = load_records(args.tracking_uri)
    data = curves(records, args.data)
    if not data:
        others = [label or "the default world" for label in data_labels(records) if label != args.data.strip()]
        raise SystemExit(f"no finished {TASK} runs on {args.data or 'the default world'} in {args.tracking_uri}: "
                         f"run `make data-efficiency` first" + (f"; runs on other data: {others}" if others else ""))
    print(markdown(data, fitted_effects(records, args.log_dir, args.data), rwn_minus_model(records, args.data),
                   dirty_points(records, args.data)))
    out = plot(data, args.out, chance=1.0 / len(GESTURES))
    print(out)
    return out


if __name__ == "__main__":
    from handradar.runs.cli import run_cli

    run_cli(lambda: main(sys.argv[1:]), usage="python -m experiments.data_efficiency [--tracking-uri URI] [--out FILE]")
